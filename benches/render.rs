//! Render throughput: one randomised frame (robots, ball, nets possible; 3×3 supersampling, noise
//! and chroma subsampling on) at the network's input size and at the camera's full size, on rayon's
//! default thread pool.

use criterion::{Criterion, criterion_group, criterion_main};
use relocd::geometry::{Camera, CameraIntrinsics, FieldModel};
use relocd::sim::{Randomisation, render};

fn render_throughput(criterion: &mut Criterion) {
    let field = FieldModel::default();
    let randomisation = Randomisation::default();
    let mut group = criterion.benchmark_group("render");
    group.sample_size(20);
    for (width, height) in [(160, 120), (640, 480)] {
        let intrinsics = CameraIntrinsics::nao_top().with_resolution(width, height);
        let frames: Vec<_> = (0..8)
            .map(|index| {
                let frame = randomisation.sample(&field, 1, index, 3);
                (Camera::new(intrinsics, &frame.pose, &frame.camera), frame)
            })
            .collect();
        let mut next = 0;
        group.bench_function(format!("{width}x{height}"), |bencher| {
            bencher.iter(|| {
                let (camera, frame) = &frames[next % frames.len()];
                next += 1;
                render(&frame.scene, camera, &frame.settings)
            })
        });
    }
    group.finish();
}

// No HTML plots: the figures that matter are the medians printed, and criterion's plotting would meet
// the `ab_glyph` font backend that relocd's own plots enable in plotters, with no font registered.
criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = render_throughput
}
criterion_main!(benches);
