//! Line percepts on real Nao V6 images (tests/data/real-images, CC BY 4.0, see its NOTICE), scored
//! against their segmentation masks in image space: the images have no camera poses, so the line
//! percepts are the pose-free crossings of `detect_in_image`, and the goal posts are checked under the
//! real robots' range of camera poses.
//!
//! `cargo test --test real_images -- --ignored --nocapture` prints the table BENCHMARKS.md quotes and
//! checks issue 18's targets (pooled precision ≥ 95%, ≥ 20 points on every image whose mask is ≥ 2%
//! line, ≤ 2 points on an image without lines). The detector does not meet the first two yet, so that
//! check is ignored by `cargo test` until it does; what it does meet (the images without lines, and
//! the pooled precision it has reached) and the scorer's own tests always run.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use image::RgbImage;
use nalgebra::Point2;
use relocd::frame::Frame;
use relocd::geometry::{CameraIntrinsics, CameraPose, FieldDimensions};
use relocd::refine::{detect, detect_in_image};

/// The mask's colour for painted lines.
const LINE: [u8; 3] = [70, 199, 10];
/// The mask's colour for the goal.
const GOAL: [u8; 3] = [199, 10, 193];
/// A point is right when the mask has a line pixel within this many pixels.
const TOLERANCE: i64 = 3;
/// The mask's classes (tests/data/real-images/NOTICE.md) other than lines, by colour.
const CLASSES: [([u8; 3], &str); 6] = [
    ([245, 41, 5], "carpet"),
    ([199, 92, 10], "ball"),
    ([10, 193, 199], "robot"),
    (GOAL, "goal"),
    ([45, 10, 199], "background"),
    ([0, 0, 0], "uncertain"),
];

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/real-images")
}

fn load(path: &Path) -> RgbImage {
    image::open(path).unwrap_or_else(|error| panic!("{}: {error}", path.display())).to_rgb8()
}

/// Whether the mask has a line pixel within `TOLERANCE` of (u, v).
fn near_line(mask: &RgbImage, u: f64, v: f64) -> bool {
    let (x, y) = (u.floor() as i64, v.floor() as i64);
    (-TOLERANCE..=TOLERANCE).any(|dy| {
        (-TOLERANCE..=TOLERANCE).any(|dx| {
            let (px, py) = (x + dx, y + dy);
            px >= 0
                && py >= 0
                && (px as u32) < mask.width()
                && (py as u32) < mask.height()
                && mask.get_pixel(px as u32, py as u32).0 == LINE
        })
    })
}

/// Centres of the mask's line runs along every `spacing`-th column and row (as the detector scans).
fn mask_crossings(mask: &RgbImage, spacing: u32) -> Vec<(f64, f64)> {
    let is_line = |x: u32, y: u32| mask.get_pixel(x, y).0 == LINE;
    let mut centres = Vec::new();
    let mut runs = |length: u32, at: &dyn Fn(u32) -> bool, place: &dyn Fn(f64) -> (f64, f64)| {
        let mut start = None;
        for i in 0..=length {
            match (i < length && at(i), start) {
                (true, None) => start = Some(i),
                (false, Some(s)) => {
                    centres.push(place((s + i) as f64 / 2.0));
                    start = None;
                }
                _ => {}
            }
        }
    };
    for x in (spacing / 2..mask.width()).step_by(spacing as usize) {
        runs(mask.height(), &|y| is_line(x, y), &|v| (x as f64 + 0.5, v));
    }
    for y in (spacing / 2..mask.height()).step_by(spacing as usize) {
        runs(mask.width(), &|x| is_line(x, y), &|u| (u, y as f64 + 0.5));
    }
    centres
}

struct Score {
    name: String,
    line_share: f64,
    points: usize,
    right: usize,
    mask_crossings: usize,
    found: usize,
    /// The points off the lines, counted by the mask's class under each.
    wrong_on: BTreeMap<&'static str, usize>,
}

/// The mask's class at (u, v), other than a line.
fn class_at(mask: &RgbImage, u: f64, v: f64) -> &'static str {
    let pixel =
        mask.get_pixel((u.floor() as u32).min(mask.width() - 1), (v.floor() as u32).min(mask.height() - 1));
    CLASSES.iter().find(|(colour, _)| *colour == pixel.0).map_or("other", |&(_, name)| name)
}

fn score(name: &str) -> Score {
    let image = load(&data().join(format!("{name}_RGB.png")));
    let mask = load(&data().join(format!("{name}.png")));
    let percepts = detect_in_image(&Frame::Rgb(image)).unwrap();
    let centres: Vec<_> = percepts.crossings.iter().map(|crossing| crossing.centre()).collect();
    let (on_lines, off_lines): (Vec<&Point2<f64>>, Vec<_>) =
        centres.iter().partition(|c| near_line(&mask, c.x, c.y));
    let mut wrong_on = BTreeMap::new();
    for c in off_lines {
        *wrong_on.entry(class_at(&mask, c.x, c.y)).or_insert(0) += 1;
    }
    let truth = mask_crossings(&mask, percepts.scan_spacing() as u32);
    let found = truth
        .iter()
        .filter(|(u, v)| centres.iter().any(|c| (c.x - u).abs().max((c.y - v).abs()) <= TOLERANCE as f64))
        .count();
    let line_pixels = mask.pixels().filter(|pixel| pixel.0 == LINE).count();
    Score {
        name: name.to_owned(),
        line_share: line_pixels as f64 / (mask.width() * mask.height()) as f64,
        points: centres.len(),
        right: on_lines.len(),
        mask_crossings: truth.len(),
        found,
        wrong_on,
    }
}

fn masked_images() -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(data())
        .unwrap()
        .filter_map(|entry| {
            let name = entry.unwrap().file_name().into_string().unwrap();
            let stem = name.strip_suffix(".png")?;
            (!stem.ends_with("_RGB")).then(|| stem.to_owned())
        })
        .collect();
    names.sort();
    names
}

#[test]
#[ignore = "issue 18's real-image targets are not met yet (BENCHMARKS.md, Real images)"]
fn line_percepts_hold_on_real_images() {
    let scores: Vec<Score> = masked_images().iter().map(|name| score(name)).collect();
    assert_eq!(scores.len(), 12, "the twelve masked images");
    println!(
        "| image | mask line share | points | on a line (≤ 3 px) | mask crossings found | off the lines, on |"
    );
    println!("|---|---|---|---|---|---|");
    for s in &scores {
        let wrong_on: Vec<String> =
            s.wrong_on.iter().map(|(class, count)| format!("{class} {count}")).collect();
        println!(
            "| {} | {:.1}% | {} | {} ({:.1}%) | {} of {} ({:.0}%) | {} |",
            s.name,
            100.0 * s.line_share,
            s.points,
            s.right,
            100.0 * s.right as f64 / s.points.max(1) as f64,
            s.found,
            s.mask_crossings,
            100.0 * s.found as f64 / s.mask_crossings.max(1) as f64,
            wrong_on.join(", ")
        );
    }
    let (points, right): (usize, usize) = scores.iter().fold((0, 0), |(p, r), s| (p + s.points, r + s.right));
    let (truth, found): (usize, usize) =
        scores.iter().fold((0, 0), |(t, f), s| (t + s.mask_crossings, f + s.found));
    let mut wrong_on: BTreeMap<&str, usize> = BTreeMap::new();
    for (class, count) in scores.iter().flat_map(|s| &s.wrong_on) {
        *wrong_on.entry(class).or_insert(0) += count;
    }
    let precision = right as f64 / points as f64;
    println!(
        "pooled: precision {:.1}% ({right} of {points}), recall {:.1}% ({found} of {truth} mask crossings); off the lines, on: {wrong_on:?}",
        100.0 * precision,
        100.0 * found as f64 / truth as f64
    );
    assert!(precision >= 0.95, "pooled precision {precision:.3}");
    for s in &scores {
        if s.line_share >= 0.02 {
            assert!(s.points >= 20, "{}: {} points on {:.1}% line", s.name, s.points, 100.0 * s.line_share);
        }
        if s.line_share == 0.0 {
            assert!(s.points <= 2, "{}: {} points without a line", s.name, s.points);
        }
    }
}

/// Pooled precision the detector has reached (BENCHMARKS.md, Real images): a floor against regressions.
const REACHED_PRECISION: f64 = 0.96;

#[test]
fn images_without_lines_stay_empty_and_the_reached_precision_holds() {
    let scores: Vec<Score> = masked_images().iter().map(|name| score(name)).collect();
    for s in scores.iter().filter(|s| s.line_share == 0.0) {
        assert!(s.points <= 2, "{}: {} points without a line", s.name, s.points);
    }
    let (points, right) = scores.iter().fold((0, 0), |(p, r), s| (p + s.points, r + s.right));
    let precision = right as f64 / points as f64;
    assert!(precision >= REACHED_PRECISION, "pooled precision {precision:.3} ({right} of {points})");
}

#[test]
fn nothing_but_a_goal_is_kept_as_a_goal_post() {
    // The images have no camera poses: under the real robots' range of heights and pitches, every
    // post the percepts keep must stand on the mask's goal (within 3 px in u, in the 20 px above its
    // foot). Robots' legs on 00104 and 00170 are upright white bars standing on the carpet, found in
    // the image; they rise less than a goal's post would.
    let dimensions = FieldDimensions::default();
    for name in masked_images() {
        let frame = Frame::Rgb(load(&data().join(format!("{name}_RGB.png"))));
        let mask = load(&data().join(format!("{name}.png")));
        for (height, pitch) in [(0.4, -5.0), (0.45, 5.0), (0.5, 15.0), (0.55, 25.0_f64)] {
            let camera = CameraPose::new(height, pitch.to_radians(), 0.0, 0.0).unwrap();
            let percepts = detect(&frame, &CameraIntrinsics::nao_top(), &camera, &dimensions).unwrap();
            for post in &percepts.posts {
                let foot = post.sighting.foot;
                let on_goal = (-TOLERANCE..=TOLERANCE).any(|du| {
                    (0..20).any(|dv| {
                        let (x, y) = (foot.x as i64 + du, foot.y as i64 - dv);
                        x >= 0
                            && y >= 0
                            && (x as u32) < mask.width()
                            && (y as u32) < mask.height()
                            && mask.get_pixel(x as u32, y as u32).0 == GOAL
                    })
                });
                assert!(on_goal, "{name} at {height} m, {pitch}°: a post at {foot:?} off the goal");
            }
        }
    }
}

#[test]
fn the_scorer_finds_the_masks_line_runs_and_judges_points_against_them() {
    let mask = load(&data().join("00096.png"));
    let truth = mask_crossings(&mask, 8);
    assert!(truth.len() > 100, "{} line runs on the scan grid", truth.len());
    for &(u, v) in &truth {
        assert!(near_line(&mask, u, v), "({u}, {v}) is the centre of a line run");
    }
    assert!(!near_line(&mask, 320.5, 40.5), "the wall at the top is not line");
    assert_eq!(masked_images().len(), 12);
}
