//! The renderer against the geometry: the field's symmetries show in the images, and known field
//! points land where the camera model says.

use image::{Rgb, RgbImage};
use nalgebra::Point3;
use relocd::geometry::{Camera, CameraIntrinsics, CameraPose, FieldModel, FieldPose, Symmetry};
use relocd::sim::{RenderSettings, Scene, Surroundings, render};

fn clean() -> RenderSettings {
    RenderSettings::default()
}

fn shot(scene: &Scene, pose: &FieldPose, camera: &CameraPose, width: u32, height: u32) -> RgbImage {
    let intrinsics = CameraIntrinsics::nao_top().with_resolution(width, height);
    render(scene, &Camera::new(intrinsics, pose, camera), &clean())
}

/// Fraction of pixels whose channels differ by more than `tolerance` levels.
fn differing_fraction(a: &RgbImage, b: &RgbImage, tolerance: u8) -> f64 {
    let differing =
        a.pixels().zip(b.pixels()).filter(|(p, q)| (0..3).any(|c| p[c].abs_diff(q[c]) > tolerance)).count();
    differing as f64 / (a.width() * a.height()) as f64
}

fn mirrored(image: &RgbImage) -> RgbImage {
    image::imageops::flip_horizontal(image)
}

fn symmetric_scene() -> Scene {
    Scene { nets: true, ..Scene::plain(FieldModel::default()) }
}

/// Poses that see lines, the circle and goals.
fn poses() -> Vec<(FieldPose, CameraPose)> {
    [(-1.3, 0.7, 0.4, 0.15), (2.9, -1.8, 2.6, 0.05), (-3.6, 2.4, -0.9, 0.3), (0.4, -0.2, -2.8, 0.2)]
        .into_iter()
        .map(|(x, y, heading, pitch)| {
            (FieldPose::new(x, y, heading).unwrap(), CameraPose::new(0.5, pitch, 0.0, 0.0).unwrap())
        })
        .collect()
}

#[test]
fn point_symmetric_poses_see_the_same_image() {
    let scene = symmetric_scene();
    for (pose, camera) in poses() {
        let image = shot(&scene, &pose, &camera, 160, 120);
        let twin = shot(&scene, &Symmetry::PointReflection.apply(&pose), &camera, 160, 120);
        let fraction = differing_fraction(&image, &twin, 2);
        assert!(fraction < 0.002, "{pose:?}: {:.2}% of pixels differ", 100.0 * fraction);
    }
}

#[test]
fn mirrored_poses_see_the_mirrored_image() {
    let scene = symmetric_scene();
    for (pose, camera) in poses() {
        let image = shot(&scene, &pose, &camera, 160, 120);
        for mirror in [Symmetry::MirrorLongAxis, Symmetry::MirrorShortAxis] {
            let twin = shot(&scene, &mirror.apply(&pose), &camera.mirrored(), 160, 120);
            let fraction = differing_fraction(&image, &mirrored(&twin), 2);
            assert!(fraction < 0.002, "{mirror:?} of {pose:?}: {:.2}% of pixels differ", 100.0 * fraction);
        }
    }
}

#[test]
fn asymmetric_surroundings_break_the_symmetry() {
    let scene = Scene { surroundings: Surroundings::Asymmetric { seed: 11 }, ..symmetric_scene() };
    let (pose, camera) = poses()[0];
    let image = shot(&scene, &pose, &camera, 160, 120);
    let twin = shot(&scene, &Symmetry::PointReflection.apply(&pose), &camera, 160, 120);
    assert!(differing_fraction(&image, &twin, 2) > 0.1, "the hall must tell the two halves apart");
}

fn pixel_at(image: &RgbImage, camera: &Camera, point: Point3<f64>) -> Rgb<u8> {
    let pixel = camera.project(&point).expect("point in front of the camera");
    assert!(camera.contains(&pixel), "{point:?} projects outside the image: {pixel:?}");
    *image.get_pixel(pixel.x as u32, pixel.y as u32)
}

fn is_white(pixel: Rgb<u8>) -> bool {
    pixel.0.iter().all(|channel| *channel > 150)
}

fn is_green(pixel: Rgb<u8>) -> bool {
    pixel[1] > pixel[0] + 20 && pixel[1] > pixel[2] + 20
}

#[test]
fn field_points_land_where_the_camera_model_projects_them() {
    let scene = Scene::plain(FieldModel::default());
    let intrinsics = CameraIntrinsics::nao_top();
    let cases = [
        // (robot pose, pitch, painted point, carpet point beside it)
        ((-4.3, 0.0, 0.0), 0.3, (-3.2, 0.0), (-3.2, 0.25)), // own penalty mark
        ((-1.0, 0.3, -0.3), 0.3, (0.0, 0.0), (0.2, 0.0)),   // centre spot
        ((2.0, -0.5, 0.4), 0.25, (3.2, 0.0), (3.2, 0.25)),  // opponent penalty mark
        ((-2.0, 2.0, 0.7), 0.2, (-1.0, 3.0), (-1.0, 2.8)),  // a touchline
    ];
    for ((x, y, heading), pitch, painted, carpet) in cases {
        let pose = FieldPose::new(x, y, heading).unwrap();
        let camera = Camera::new(intrinsics, &pose, &CameraPose::new(0.5, pitch, 0.0, 0.0).unwrap());
        let image = render(&scene, &camera, &clean());
        let on_paint = pixel_at(&image, &camera, Point3::new(painted.0, painted.1, 0.0));
        let beside = pixel_at(&image, &camera, Point3::new(carpet.0, carpet.1, 0.0));
        assert!(is_white(on_paint), "{painted:?} from {pose:?} should be white, is {on_paint:?}");
        assert!(is_green(beside), "{carpet:?} from {pose:?} should be carpet, is {beside:?}");
    }
}

#[test]
fn goal_post_lands_where_the_camera_model_projects_it() {
    let scene = Scene::plain(FieldModel::default());
    let post = scene.field.goals[1].posts[0];
    let pose = FieldPose::new(2.5, 0.3, 0.0).unwrap();
    let camera =
        Camera::new(CameraIntrinsics::nao_top(), &pose, &CameraPose::new(0.5, 0.0, 0.0, 0.0).unwrap());
    let image = render(&scene, &camera, &clean());
    let on_post = pixel_at(&image, &camera, Point3::new(post.x, post.y, 0.6));
    let beside = pixel_at(&image, &camera, Point3::new(post.x, post.y + 0.4, 0.6));
    assert!(on_post.0.iter().all(|channel| *channel > 100), "post pixel {on_post:?}");
    assert_eq!(beside, Rgb([0, 0, 0]), "beside the post the black surroundings show");
}

#[test]
fn a_robot_casts_a_shadow_only_when_shadows_are_on() {
    use nalgebra::{Point2, Vector3};
    use relocd::sim::{Lighting, Robot, SecondLight};
    // Light from 30° off vertical, from +x: the shadow falls towards the camera at −x.
    let lighting = Lighting { direction: Vector3::new(0.5, 0.0, 0.866), ..Lighting::default() };
    let robot = Robot { position: Point2::new(1.0, 0.5), jersey: [0.1, 0.1, 0.6] };
    let lit = Scene { lighting, robots: vec![robot], ..Scene::plain(FieldModel::default()) };
    let shaded = Scene { shadows: true, ..lit.clone() };
    let pose = FieldPose::new(0.0, 0.5, 0.0).unwrap();
    let camera =
        Camera::new(CameraIntrinsics::nao_top(), &pose, &CameraPose::new(0.5, 0.35, 0.0, 0.0).unwrap());
    // A ground point just in front of the robot's leg (radius 0.08 m), which the leg hides from the light.
    let ground = Point3::new(0.86, 0.5, 0.0);
    let brightness = |scene: &Scene| {
        let pixel = pixel_at(&render(scene, &camera, &clean()), &camera, ground);
        pixel.0.iter().map(|channel| u32::from(*channel)).sum::<u32>()
    };
    let (without, with) = (brightness(&lit), brightness(&shaded));
    assert!(with < without * 9 / 10, "shadow {with} vs lit {without}");
    // Far from the robot, shadows change nothing.
    let open = Point3::new(1.5, 0.9, 0.0);
    let far = |scene: &Scene| pixel_at(&render(scene, &camera, &clean()), &camera, open);
    assert_eq!(far(&lit), far(&shaded));

    // A second lamp from +x casts its own, fainter shadow when the main light is overhead.
    let overhead = Lighting {
        second: Some(SecondLight { direction: Vector3::new(0.5, 0.0, 0.866), share: 0.4 }),
        ..Lighting::default()
    };
    let two_lamps = Scene { lighting: overhead, ..shaded.clone() };
    let faint = brightness(&two_lamps);
    let unshadowed = brightness(&Scene { shadows: false, ..two_lamps.clone() });
    assert!(faint < unshadowed && faint > with, "second-lamp shadow {faint}, lit {unshadowed}, full {with}");
}

#[test]
fn wear_textures_the_carpet_and_blur_smears_edges() {
    use relocd::sim::Wear;
    let plain = Scene::plain(FieldModel::default());
    let worn = Scene { wear: Some(Wear { seed: 3, carpet: 0.3, paint: 0.6 }), ..plain.clone() };
    let pose = FieldPose::new(-2.0, 1.0, -0.3).unwrap();
    let camera = CameraPose::new(0.5, 0.3, 0.0, 0.0).unwrap();
    let (clean_shot, worn_shot) =
        (shot(&plain, &pose, &camera, 160, 120), shot(&worn, &pose, &camera, 160, 120));
    assert!(differing_fraction(&clean_shot, &worn_shot, 4) > 0.3, "the texture changes the carpet");
    let intrinsics = CameraIntrinsics::nao_top().with_resolution(160, 120);
    let placed = Camera::new(intrinsics, &pose, &camera);
    let blurred = RenderSettings { motion_blur: [0.05, 0.0], ..clean() };
    let smeared = render(&plain, &placed, &blurred);
    let changed = differing_fraction(&clean_shot, &smeared, 8);
    assert!(changed > 0.005 && changed < 0.5, "blur changes the edges only: {changed}");
}

#[test]
fn hall_realism_changes_the_scene_but_not_the_pose() {
    use relocd::sim::Randomisation;
    let field = FieldModel::default();
    let plain = Randomisation::default();
    let real = Randomisation { hall_realism: true, ..Randomisation::default() };
    for index in 0..8 {
        let (a, b) = (plain.sample(&field, 9, index, 1), real.sample(&field, 9, index, 1));
        assert_eq!((a.pose, a.camera), (b.pose, b.camera), "frame {index}");
        assert!(b.scene.shadows && b.scene.wear.is_some() && !a.scene.shadows && a.scene.wear.is_none());
        assert_ne!(b.scene.surroundings, Surroundings::Black);
        assert!(b.scene.robots.len() >= a.scene.robots.len());
    }
}
