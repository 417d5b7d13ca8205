//! Line refinement on rendered frames: percepts land on the true lines, perturbed poses come back,
//! the lines down-weight what they contradict and tie point-symmetric twins, frames without lines stay
//! unrefined, and bad inputs are clear errors.
//!
//! `RELOCD_REFINE_FRAMES=N cargo test --release --test refine -- --nocapture` runs the convergence
//! check on N frames and prints the figures (BENCHMARKS.md, "Line refinement"); with
//! `RELOCD_REFINE_REALISM=1`, on frames with hall realism.

use image::{Rgb, RgbImage};
use relocd::frame::{Frame, YuyvImage};
use relocd::geometry::angle::angle_distance;
use relocd::geometry::{Camera, CameraIntrinsics, CameraPose, FieldModel, FieldPose, PoseSigma, Symmetry};
use relocd::pipeline::{GlobalSearch, Hypothesis, Pipeline, Priors, verify};
use relocd::refine::line_map::Primitive;
use relocd::refine::{CalibrationTracker, FramePercepts, Guess, LineCheck, LineRefiner, PerceptError};
use relocd::sim::{Randomisation, SampledFrame, render};

/// Seed of the frames rendered here: never used for training.
const SEED: u64 = 7100;

fn rendered(index: u64) -> (SampledFrame, Frame) {
    rendered_with(Randomisation::default(), index)
}

/// Frames with what real halls add (`render --hall-realism`).
fn rendered_in_a_hall(index: u64) -> (SampledFrame, Frame) {
    rendered_with(Randomisation { hall_realism: true, ..Randomisation::default() }, index)
}

fn rendered_with(randomisation: Randomisation, index: u64) -> (SampledFrame, Frame) {
    let field = FieldModel::default();
    let sampled = randomisation.sample(&field, SEED, index, 2);
    let camera = Camera::new(CameraIntrinsics::nao_top(), &sampled.pose, &sampled.camera);
    let image = render(&sampled.scene, &camera, &sampled.settings);
    (sampled, Frame::Rgb(image))
}

fn percepts(refiner: &LineRefiner, sampled: &SampledFrame, frame: &Frame) -> FramePercepts {
    refiner.percepts(frame, &CameraIntrinsics::nao_top(), &sampled.camera).unwrap()
}

fn hypotheses(weighted: &[(FieldPose, f64)], sigma: PoseSigma) -> Vec<Hypothesis> {
    weighted.iter().map(|&(pose, weight)| Hypothesis { pose, weight, sigma, lines: None }).collect()
}

/// The CNN-like spread the refinement starts from.
fn cnn_sigma() -> PoseSigma {
    PoseSigma { x: 0.35, y: 0.35, theta: 10f64.to_radians() }
}

/// Whether the frame's points (placed with the true pose) lie on two non-parallel lines (or on the
/// circle and a line): the frames on which a full refinement is possible.
fn sees_two_directions(refiner: &LineRefiner, percepts: &FramePercepts, truth: &FieldPose) -> bool {
    let mut directions: Vec<Option<f64>> = Vec::new();
    for primitive in refiner.map().primitives() {
        let on_it = percepts
            .points
            .iter()
            .filter(|p| {
                let field = truth.robot_to_field(p.ground);
                refiner.map().nearest(field) == primitive && primitive.residual(field).0 < 0.05
            })
            .count();
        if on_it >= 5 {
            directions.push(match primitive {
                Primitive::Segment { start, end } => Some((end.y - start.y).atan2(end.x - start.x)),
                Primitive::Circle { .. } => None,
            });
        }
    }
    directions.iter().enumerate().any(|(i, a)| {
        directions[i + 1..].iter().any(|b| match (a, b) {
            (Some(a), Some(b)) => (a - b).sin().abs() > 0.5,
            _ => true,
        })
    })
}

/// The first rendered frame with plenty of line points on two line directions, and its percepts.
fn frame_with_lines(refiner: &LineRefiner) -> (SampledFrame, FramePercepts) {
    (0..40)
        .map(rendered)
        .map(|(sampled, frame)| {
            let percepts = percepts(refiner, &sampled, &frame);
            (sampled, percepts)
        })
        .find(|(sampled, percepts)| {
            percepts.points.len() > 100 && sees_two_directions(refiner, percepts, &sampled.pose)
        })
        .expect("a frame with lines")
}

/// Distances of the line points of frames 0..12 from the true lines, sorted.
fn distances_from_the_true_lines(render: fn(u64) -> (SampledFrame, Frame)) -> Vec<f64> {
    let field = FieldModel::default();
    let refiner = LineRefiner::new(&field);
    let mut distances = Vec::new();
    for index in 0..12 {
        let (sampled, frame) = render(index);
        for point in percepts(&refiner, &sampled, &frame).points {
            distances.push(field.distance_to_nearest_line(sampled.pose.robot_to_field(point.ground)));
        }
    }
    distances.sort_by(f64::total_cmp);
    distances
}

#[test]
fn percepts_land_on_the_true_lines() {
    let distances = distances_from_the_true_lines(rendered);
    assert!(distances.len() > 300, "only {} line points in 12 frames", distances.len());
    let median = distances[distances.len() / 2];
    let p95 = distances[distances.len() * 95 / 100];
    assert!(median < 0.02 && p95 < 0.06, "median {median:.3} m, 95th percentile {p95:.3} m");
}

#[test]
fn percepts_survive_shadows_wear_blur_and_a_cluttered_hall() {
    let distances = distances_from_the_true_lines(rendered_in_a_hall);
    assert!(distances.len() > 200, "only {} line points in 12 frames", distances.len());
    let median = distances[distances.len() / 2];
    let p90 = distances[distances.len() * 9 / 10];
    assert!(median < 0.03 && p90 < 0.1, "median {median:.3} m, 90th percentile {p90:.3} m");
}

#[test]
fn refinement_recovers_perturbed_poses() {
    let frames: u64 = std::env::var("RELOCD_REFINE_FRAMES").ok().and_then(|n| n.parse().ok()).unwrap_or(40);
    // RELOCD_REFINE_REALISM=1: the same on frames with hall realism.
    let render =
        if std::env::var_os("RELOCD_REFINE_REALISM").is_some() { rendered_in_a_hall } else { rendered };
    // Rendered frames carry their exact camera pose: nothing to correct.
    let refiner = LineRefiner::new(&FieldModel::default()).with_camera_correction(false);
    let (mut eligible, mut recovered) = (0usize, 0usize);
    for index in 0..frames {
        let (sampled, frame) = render(index);
        let percepts = percepts(&refiner, &sampled, &frame);
        if !sees_two_directions(&refiner, &percepts, &sampled.pose) {
            continue;
        }
        eligible += 1;
        // Perturbed by up to 50 cm and 15°, in a direction that depends on the frame.
        let angle = index as f64 * 2.399;
        let truth = sampled.pose;
        let start = FieldPose::new(
            truth.x() + 0.5 * angle.cos() * (0.4 + 0.6 * ((index % 5) as f64 / 4.0)),
            truth.y() + 0.5 * angle.sin() * (0.4 + 0.6 * ((index % 5) as f64 / 4.0)),
            truth.heading() + 15f64.to_radians() * (index as f64 * 0.7).sin(),
        )
        .unwrap();
        let mut estimate = hypotheses(&[(start, 1.0)], cnn_sigma());
        verify(&refiner, std::slice::from_ref(&percepts), &mut estimate, &[], GlobalSearch::Never);
        let result = &estimate[0];
        let heading_error = (result.pose.heading() - truth.heading()).sin().abs().asin().to_degrees();
        if result.pose.distance_to(&truth) <= 0.05 && heading_error <= 1.0 {
            recovered += 1;
        } else {
            eprintln!("frame {index}: {:?} from {start:?}, truth {truth:?}, {:?}", result.pose, result.lines);
        }
    }
    let share = recovered as f64 / eligible as f64;
    eprintln!(
        "{recovered} of {eligible} frames seeing two line directions recovered ({share:.3}); {frames} rendered"
    );
    assert!(eligible >= frames as usize / 3, "only {eligible} of {frames} frames see two line directions");
    assert!(share >= 0.95, "{recovered} of {eligible} recovered");
}

#[test]
fn lines_down_weight_a_contradicted_hypothesis_and_tie_point_twins() {
    let refiner = LineRefiner::new(&FieldModel::default()).with_camera_correction(false);
    let (sampled, percepts) = frame_with_lines(&refiner);
    let truth = sampled.pose;
    let twin = Symmetry::PointReflection.apply(&truth);
    // A wrong hypothesis: the mirror image, which sees the lines mirrored.
    let wrong = Symmetry::MirrorLongAxis.apply(&truth);
    let mut estimate = hypotheses(&[(truth, 0.3), (twin, 0.2), (wrong, 0.5)], cnn_sigma());
    verify(&refiner, std::slice::from_ref(&percepts), &mut estimate, &[], GlobalSearch::Never);
    let find =
        |pose: &FieldPose| estimate.iter().find(|h| h.pose.distance_to(pose) < 0.2).expect("hypothesis kept");
    let (kept, kept_twin, contradicted) = (find(&truth), find(&twin), find(&wrong));
    assert_eq!(contradicted.lines.unwrap().check, LineCheck::Contradicted, "{:?}", contradicted.lines);
    assert!(contradicted.weight < 0.1 * kept.weight, "{} vs {}", contradicted.weight, kept.weight);
    assert_eq!(kept.lines.unwrap().check, LineCheck::Refined);
    // The twins keep the ratio of their network weights: the lines score them the same.
    assert_eq!(kept.lines, kept_twin.lines);
    assert!((kept.weight / kept_twin.weight - 1.5).abs() < 1e-9, "{} / {}", kept.weight, kept_twin.weight);
    assert!(Symmetry::PointReflection.apply(&kept.pose).distance_to(&kept_twin.pose) < 1e-9);
    let total: f64 = estimate.iter().map(|h| h.weight).sum();
    assert!((total - 1.0).abs() < 1e-9);
}

#[test]
fn the_true_pose_passes_its_check_and_a_wrong_one_shows_where_it_disagrees() {
    let refiner = LineRefiner::new(&FieldModel::default()).with_camera_correction(false);
    let (sampled, percepts) = frame_with_lines(&refiner);
    let frames = std::slice::from_ref(&percepts);
    let at_truth = refiner.check_at(frames, &sampled.pose).expect("enough points");
    assert!(at_truth.passes(), "{at_truth:?}");
    assert!(at_truth.off_lines.is_empty() && at_truth.inlier_share == 1.0, "{at_truth:?}");
    assert_eq!(at_truth.points, at_truth.fit.evidence.points);
    assert_eq!(at_truth.fit.evidence.check, LineCheck::Refined);
    assert!(at_truth.fit.pose.distance_to(&sampled.pose) < 0.05, "{:?}", at_truth.fit.pose);
    // Half a metre sideways and 20° turned, the points miss the lines and the lines the camera should
    // see there are missing; each is named by its frame and pixel, inside the image.
    let truth = sampled.pose;
    let wrong = FieldPose::new(truth.x() + 0.5, truth.y(), truth.heading() + 20f64.to_radians()).unwrap();
    let check = refiner.check_at(frames, &wrong).expect("enough points");
    assert!(!check.passes(), "{check:?}");
    assert!(!check.inlier_share_passes() && check.inlier_share < 0.8, "{}", check.inlier_share);
    assert_eq!(check.off_lines.len(), ((1.0 - check.inlier_share) * check.points as f64).round() as usize);
    let (width, height) = percepts.image().dimensions();
    for &(frame, pixel) in check.off_lines.iter().chain(&check.unseen) {
        assert_eq!(frame, 0);
        assert!((0.0..width as f64).contains(&pixel.x) && (0.0..height as f64).contains(&pixel.y), "{pixel}");
    }
    // Too few points: nothing to check.
    let mut few = percepts.clone();
    few.points.truncate(5);
    assert!(refiner.check_at(std::slice::from_ref(&few), &truth).is_none());
}

#[test]
fn a_prior_guess_near_the_truth_finds_the_place_a_lost_network_missed() {
    let refiner = LineRefiner::new(&FieldModel::default()).with_camera_correction(false);
    let (sampled, percepts) = frame_with_lines(&refiner);
    let truth = sampled.pose;
    let found = |estimate: &[Hypothesis]| {
        estimate.iter().any(|h| {
            [truth, Symmetry::PointReflection.apply(&truth)].iter().any(|pose| {
                h.pose.distance_to(pose) <= 0.05
                    && (h.pose.heading() - pose.heading()).sin().abs() <= 1f64.to_radians().sin()
            })
        })
    };
    // The network is lost: its twins sit at the mirror image, which the lines contradict.
    let lost = Symmetry::MirrorLongAxis.apply(&truth);
    let network = hypotheses(&[(lost, 0.5), (Symmetry::PointReflection.apply(&lost), 0.5)], cnn_sigma());
    let mut alone = network.clone();
    verify(&refiner, std::slice::from_ref(&percepts), &mut alone, &[], GlobalSearch::Never);
    assert!(!found(&alone), "the lines alone should not reach the truth from {lost:?}: {alone:?}");
    // The team's belief, 80 cm and 20° off, claiming half of that as its σ.
    let belief = Guess {
        pose: FieldPose::new(truth.x() + 0.6, truth.y() - 0.53, truth.heading() + 20f64.to_radians())
            .unwrap(),
        sigma: PoseSigma { x: 0.4, y: 0.4, theta: 10f64.to_radians() },
    };
    let mut helped = network.clone();
    verify(&refiner, std::slice::from_ref(&percepts), &mut helped, &[belief], GlobalSearch::Never);
    assert!(found(&helped), "{truth:?} not among {helped:?}");
    let total: f64 = helped.iter().map(|h| h.weight).sum();
    assert!((total - 1.0).abs() < 1e-9);
    // A guess where the lines fit nothing adds nothing: the network's hypotheses stay the hypotheses.
    let nowhere = Guess { pose: lost, sigma: PoseSigma { x: 0.05, y: 0.05, theta: 0.02 } };
    let mut unhelped = network.clone();
    verify(&refiner, std::slice::from_ref(&percepts), &mut unhelped, &[nowhere], GlobalSearch::Never);
    assert_eq!(unhelped.len(), network.len());
    assert_eq!(unhelped.iter().map(|h| h.lines.unwrap().places).collect::<Vec<_>>(), [None, None]);
}

#[test]
fn along_a_lone_line_the_hypotheses_keep_the_networks_spread() {
    let refiner = LineRefiner::new(&FieldModel::default()).with_camera_correction(false);
    // The first rendered frame whose lines, at the true pose, fix it across one line only.
    let (truth, percepts, free) = (0..80)
        .map(rendered)
        .find_map(|(sampled, frame)| {
            let percepts = percepts(&refiner, &sampled, &frame);
            let check = refiner.check_at(std::slice::from_ref(&percepts), &sampled.pose)?;
            let information = check.fit.line_information.fixed_view::<2, 2>(0, 0).into_owned();
            let eigen = nalgebra::SymmetricEigen::new(information);
            let (weakest, strongest) = (eigen.eigenvalues.imin(), eigen.eigenvalues.imax());
            // Across the line a point's σ of 1.5 cm; along it, nothing.
            let lone = check.passes()
                && eigen.eigenvalues[strongest] > 1e4
                && eigen.eigenvalues[weakest] < 1e-3 * eigen.eigenvalues[strongest];
            lone.then(|| (sampled.pose, percepts, eigen.eigenvectors.column(weakest).into_owned()))
        })
        .expect("a frame along one line");
    // An honest network, 1.5 m off along the line and saying it may be a metre off.
    let guess = FieldPose::new(truth.x() + 1.5 * free.x, truth.y() + 1.5 * free.y, truth.heading()).unwrap();
    let sigma = PoseSigma { x: 1.0, y: 1.0, theta: 5f64.to_radians() };
    let mut estimate = hypotheses(&[(guess, 0.5), (Symmetry::PointReflection.apply(&guess), 0.5)], sigma);
    verify(&refiner, std::slice::from_ref(&percepts), &mut estimate, &[], GlobalSearch::WhenUnsure);
    let holds_the_truth = |h: &Hypothesis| {
        (h.pose.x() - truth.x()).abs() <= 3.0 * h.sigma.x
            && (h.pose.y() - truth.y()).abs() <= 3.0 * h.sigma.y
            && angle_distance(h.pose.heading(), truth.heading()) <= 3.0 * h.sigma.theta
    };
    let holding = estimate.iter().find(|h| holds_the_truth(h));
    let holding = holding.unwrap_or_else(|| panic!("no hypothesis holds {truth:?} within 3 σ: {estimate:?}"));
    // What the lines fix stays fixed; along the line the σ is the network's, not a fit's step.
    let along = (holding.sigma.x * free.x).hypot(holding.sigma.y * free.y);
    let across = (holding.sigma.x * free.y).hypot(holding.sigma.y * free.x);
    assert!(along > 0.5 && across < 0.2, "σ along {along:.3} m, across {across:.3} m: {holding:?}");
}

#[test]
fn a_camera_pitch_error_is_learnt_over_bursts() {
    // The robot believes its camera pitched 0.7° further down than it is, on every frame.
    let error = 0.7_f64.to_radians();
    let pipeline = Pipeline::lines_only(&FieldModel::default(), CameraIntrinsics::nao_top());
    let mut tracker = CalibrationTracker::default();
    let mut off_after_learning = Vec::new();
    for index in 0..30 {
        let (sampled, frame) = rendered(index);
        let believed = sampled.camera.corrected(error, 0.0).unwrap();
        let mut burst = pipeline.calibrated_burst(tracker.calibration());
        burst.add(&frame, sampled.camera.head_yaw(), Some(&believed)).unwrap();
        let Ok(estimate) = burst.finish(&Priors::default()).0 else { continue };
        if tracker.learnt() > 0 && estimate.camera.is_some() {
            let best = &estimate.hypotheses[0];
            let twin = Symmetry::PointReflection.apply(&best.pose);
            off_after_learning
                .push(best.pose.distance_to(&sampled.pose).min(twin.distance_to(&sampled.pose)));
        }
        if let Some(measured) = &estimate.camera {
            tracker.learn(measured);
        }
    }
    let learnt = tracker.calibration().correction;
    assert!(tracker.learnt() >= 4, "{tracker}");
    assert!((learnt.x + error).abs() < 0.15_f64.to_radians(), "{tracker}");
    assert!(learnt.y.abs() < 0.15_f64.to_radians(), "{tracker}");
    assert!(tracker.calibration().sigma.x < 0.5_f64.to_radians(), "{tracker}");
    assert!(!off_after_learning.is_empty());
    assert!(off_after_learning.iter().all(|&off| off < 0.05), "{off_after_learning:?}");
}

#[test]
fn frames_without_lines_stay_unrefined() {
    let refiner = LineRefiner::new(&FieldModel::default());
    let camera = CameraPose::new(0.5, 0.2, 0.0, 0.0).unwrap();
    let carpet = Frame::Rgb(RgbImage::from_pixel(640, 480, Rgb([60, 130, 50])));
    let black = Frame::Rgb(RgbImage::from_pixel(640, 480, Rgb([3, 3, 3])));
    let noise = Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| {
        let value = ((x * 7919 + y * 104_729) % 251) as u8;
        Rgb([value, value.wrapping_mul(3), value.wrapping_mul(7)])
    }));
    let pose = FieldPose::new(-1.0, 1.0, 0.5).unwrap();
    for frame in [carpet, black, noise] {
        let percepts = refiner.percepts(&frame, &CameraIntrinsics::nao_top(), &camera).unwrap();
        let mut estimate = hypotheses(&[(pose, 1.0)], cnn_sigma());
        verify(&refiner, std::slice::from_ref(&percepts), &mut estimate, &[], GlobalSearch::Never);
        let only = &estimate[0];
        assert_eq!(only.lines.unwrap().check, LineCheck::Unrefined);
        assert_eq!((only.pose, only.sigma), (pose, cnn_sigma()), "the network's hypothesis as it was");
    }
}

#[test]
fn bad_inputs_are_clear_errors() {
    let refiner = LineRefiner::new(&FieldModel::default());
    let camera = CameraPose::new(0.5, 0.2, 0.0, 0.0).unwrap();
    let empty = Frame::Rgb(RgbImage::new(0, 0));
    assert_eq!(
        refiner.percepts(&empty, &CameraIntrinsics::nao_top(), &camera).unwrap_err(),
        PerceptError::EmptyFrame { width: 0, height: 0 }
    );
    let frame = Frame::Rgb(RgbImage::new(64, 48));
    let blind = CameraIntrinsics { horizontal_fov: f64::NAN, ..CameraIntrinsics::nao_top() };
    let error = refiner.percepts(&frame, &blind, &camera).unwrap_err().to_string();
    assert!(error.contains("not a usable pinhole"), "{error}");
    let nan = CameraPose::new(0.5, f64::NAN, 0.0, 0.0).unwrap_err().to_string();
    assert!(nan.contains("pitch"), "{nan}");
    let impossible = CameraPose::new(0.5, 2.0, 0.0, 0.0).unwrap_err().to_string();
    assert!(impossible.contains("pitch"), "{impossible}");
}

#[test]
fn yuyv_frames_give_the_same_line_points_as_rgb() {
    let refiner = LineRefiner::new(&FieldModel::default());
    let (sampled, frame) = rendered(3);
    let Frame::Rgb(image) = &frame else { unreachable!("rendered frames are RGB") };
    let yuyv = Frame::Yuyv(YuyvImage::from_rgb(image).unwrap());
    let (from_rgb, from_yuyv) = (percepts(&refiner, &sampled, &frame), percepts(&refiner, &sampled, &yuyv));
    assert!(from_rgb.points.len() > 50, "{}", from_rgb.points.len());
    let ratio = from_yuyv.points.len() as f64 / from_rgb.points.len() as f64;
    assert!((0.9..=1.1).contains(&ratio), "{} vs {}", from_yuyv.points.len(), from_rgb.points.len());
    for point in &from_yuyv.points {
        assert!(point.ground.x > 0.0, "behind the camera: {point:?}");
        let nearest =
            from_rgb.points.iter().map(|p| (p.ground - point.ground).norm()).fold(f64::INFINITY, f64::min);
        assert!(nearest < 0.1, "{point:?} has no RGB counterpart");
    }
}
