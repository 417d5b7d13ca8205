//! Goal posts found in rendered frames, against the posts projected under the true pose.
//!
//! `RELOCD_POST_FRAMES=N RELOCD_POST_SEED=S [RELOCD_POST_REALISM=1] cargo test --release --test posts
//! -- --nocapture` measures N frames of seed S and prints the figures (BENCHMARKS.md, "Goal posts").

use nalgebra::{Point2, Point3};
use relocd::frame::Frame;
use relocd::geometry::{Camera, CameraIntrinsics, FieldModel};
use relocd::refine::detect;
use relocd::sim::{Randomisation, render};

/// Seed of the frames rendered here by default: never used for training or tuning.
const SEED: u64 = 7120;
/// Frames measured by default.
const FRAMES: u64 = 40;

/// Where a post should be seen: its foot's centre and its width, pixels.
struct Expected {
    foot: Point2<f64>,
    width: f64,
}

/// The posts whose foot and a stretch above it project into the image, clear of its side edges.
fn expected_posts(field: &FieldModel, camera: &Camera) -> Vec<Expected> {
    let (width, height) = (f64::from(camera.intrinsics().width), f64::from(camera.intrinsics().height));
    field
        .goals
        .iter()
        .flat_map(|goal| goal.posts.iter().map(move |post| (goal, post)))
        .filter_map(|(goal, post)| {
            let foot = camera.project(&Point3::new(post.x, post.y, 0.0))?;
            let above = camera.project(&Point3::new(post.x, post.y, goal.height / 2.0))?;
            let distance = (camera.position().xy() - Point3::new(post.x, post.y, 0.0).xy()).norm();
            let post_width = 2.0 * goal.post_radius * camera.intrinsics().focal_lengths().0 / distance;
            let inside = |pixel: Point2<f64>| {
                pixel.x >= post_width + 3.0 && pixel.x <= width - post_width - 3.0 && pixel.y >= 0.0
            };
            (inside(foot) && inside(above) && foot.y < height).then_some(Expected { foot, width: post_width })
        })
        .collect()
}

/// Whether a post found at `foot`, `width` wide, is the expected one.
fn matches(expected: &Expected, foot: &Point2<f64>) -> bool {
    (expected.foot.x - foot.x).abs() <= (expected.width / 2.0).max(3.0)
        && (expected.foot.y - foot.y).abs() <= expected.width + 6.0
}

/// Posts found against the posts expected in view.
#[derive(Clone, Copy, Debug, Default)]
struct Tally {
    found: usize,
    right: usize,
    expected: usize,
    recalled: usize,
}

impl Tally {
    fn add(&mut self, found: &[Point2<f64>], expected: &[Expected]) {
        self.found += found.len();
        self.right += found.iter().filter(|foot| expected.iter().any(|e| matches(e, foot))).count();
        self.expected += expected.len();
        self.recalled += expected.iter().filter(|e| found.iter().any(|foot| matches(e, foot))).count();
    }

    fn precision(&self) -> f64 {
        self.right as f64 / self.found.max(1) as f64
    }

    fn recall(&self) -> f64 {
        self.recalled as f64 / self.expected.max(1) as f64
    }

    fn describe(&self) -> String {
        format!(
            "{} posts found, {} right ({:.1}%); {} in view, {} found ({:.1}%)",
            self.found,
            self.right,
            100.0 * self.precision(),
            self.expected,
            self.recalled,
            100.0 * self.recall()
        )
    }
}

/// The posts of `frames` frames of `seed`: in the image, and those the ground stage keeps under the
/// frame's camera (rising as a goal's post would).
fn measure(seed: u64, frames: u64, hall_realism: bool) -> (Tally, Tally) {
    let field = FieldModel::default();
    let randomisation = Randomisation { hall_realism, ..Randomisation::default() };
    let (mut in_image, mut kept) = (Tally::default(), Tally::default());
    for index in 0..frames {
        let sampled = randomisation.sample(&field, seed, index, 2);
        let intrinsics = CameraIntrinsics::nao_top();
        let camera = Camera::new(intrinsics, &sampled.pose, &sampled.camera);
        let frame = Frame::Rgb(render(&sampled.scene, &camera, &sampled.settings));
        let percepts = detect(&frame, &intrinsics, &sampled.camera, field.dimensions()).unwrap();
        let posts: Vec<Point2<f64>> =
            percepts.image().goal_posts(&frame).iter().map(|post| post.foot).collect();
        let on_ground: Vec<Point2<f64>> = percepts.posts.iter().map(|post| post.sighting.foot).collect();
        let expected = expected_posts(&field, &camera);
        in_image.add(&posts, &expected);
        kept.add(&on_ground, &expected);
        if std::env::var_os("RELOCD_POST_VERBOSE").is_some() {
            let feet: Vec<_> = posts.iter().map(|foot| (foot.x.round(), foot.y.round())).collect();
            let truth: Vec<_> = expected.iter().map(|e| (e.foot.x.round(), e.foot.y.round())).collect();
            println!("frame {index}: found {feet:?} (kept {}), expected {truth:?}", on_ground.len());
        }
    }
    (in_image, kept)
}

#[test]
fn goal_posts_are_found_where_they_stand() {
    let frames = std::env::var("RELOCD_POST_FRAMES").ok().and_then(|n| n.parse().ok()).unwrap_or(FRAMES);
    let seed = std::env::var("RELOCD_POST_SEED").ok().and_then(|n| n.parse().ok()).unwrap_or(SEED);
    let realism = std::env::var_os("RELOCD_POST_REALISM").is_some();
    let (in_image, kept) = measure(seed, frames, realism);
    println!(
        "seed {seed}, {frames} frames{}: in the image {}; kept on the ground {}",
        if realism { " (hall realism)" } else { "" },
        in_image.describe(),
        kept.describe()
    );
    assert!(in_image.expected >= 10, "too few posts in view to measure ({})", in_image.expected);
    for (stage, tally) in [("in the image", in_image), ("kept", kept)] {
        assert!(tally.precision() >= 0.9, "{stage}: {}", tally.describe());
        assert!(tally.recall() >= 0.5, "{stage}: {}", tally.describe());
    }
    // The ground stage only drops posts.
    assert!(kept.found <= in_image.found && kept.recalled <= in_image.recalled);
}

#[test]
fn a_post_s_bearing_on_the_ground_is_the_true_post_s() {
    // The bearings the line fit uses: each post found, put on the ground under the frame's camera,
    // points within 1° at a field post under the true pose.
    let field = FieldModel::default();
    let randomisation = Randomisation::default();
    let (mut posts, mut right) = (0, 0);
    for index in 0..FRAMES {
        let sampled = randomisation.sample(&field, SEED, index, 2);
        let intrinsics = CameraIntrinsics::nao_top();
        let camera = Camera::new(intrinsics, &sampled.pose, &sampled.camera);
        let frame = Frame::Rgb(render(&sampled.scene, &camera, &sampled.settings));
        let percepts = detect(&frame, &intrinsics, &sampled.camera, field.dimensions()).unwrap();
        for post in &percepts.posts {
            posts += 1;
            let nearest = field
                .goal_posts()
                .map(|true_post| {
                    let seen = sampled.pose.field_to_robot(true_post);
                    let difference = seen.y.atan2(seen.x) - post.bearing();
                    difference.sin().atan2(difference.cos()).abs()
                })
                .fold(f64::INFINITY, f64::min);
            if nearest < 1.0_f64.to_radians() {
                right += 1;
            }
        }
    }
    assert!(posts >= 10, "too few posts found to measure ({posts})");
    assert!(right as f64 >= 0.9 * posts as f64, "{right} of {posts} bearings within 1°");
}
