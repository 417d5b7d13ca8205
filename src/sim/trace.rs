//! Casting one ray into the scene: intersections with the ground, goals, robots, ball and hall, and
//! the shaded colour of what it hits.

use std::cell::Cell;

use nalgebra::{Point2, Point3, Vector3};

use super::colour::{Linear, hsv_to_linear};
use super::scene::{BALL_RADIUS, Scene, Surroundings, body};

/// Rays closer than this are treated as starting on the surface.
const EPSILON: f64 = 1e-9;
/// Fraction of light a goal net blocks.
const NET_OPACITY: f64 = 0.35;
/// Distance of the hall walls beyond the carpet's edge, metres.
const HALL_MARGIN: f64 = 1.5;
/// Height of the hall's ceiling, metres.
const HALL_HEIGHT: f64 = 4.0;
/// Size of the coloured panels on the hall walls, metres (width, height).
const PANEL_SIZE: (f64, f64) = (1.2, 0.8);

/// A ray from the camera.
pub(super) struct Ray {
    pub origin: Point3<f64>,
    pub direction: Vector3<f64>,
}

impl Ray {
    fn at(&self, t: f64) -> Point3<f64> {
        self.origin + self.direction * t
    }
}

/// The nearest solid surface along a ray.
struct Hit {
    t: f64,
    albedo: Linear,
    normal: Vector3<f64>,
}

impl Hit {
    fn keep_nearer(best: &mut Option<Hit>, candidate: Option<Hit>) {
        if let Some(candidate) = candidate
            && best.as_ref().is_none_or(|best| candidate.t < best.t)
        {
            *best = Some(candidate);
        }
    }
}

/// Colour (linear RGB) seen along `ray`.
pub(super) fn trace(scene: &Scene, ray: &Ray) -> Linear {
    let mut nearest = None;
    for goal in &scene.field.goals {
        for post in goal.posts {
            let hit = vertical_cylinder(ray, post, goal.post_radius, 0.0, goal.height);
            Hit::keep_nearer(&mut nearest, hit.map(|(t, normal)| Hit { t, albedo: scene.white, normal }));
        }
        let crossbar = crossbar(
            ray,
            goal.posts[0].x,
            goal.height - goal.post_radius,
            goal.post_radius,
            goal.posts[1].y,
            goal.posts[0].y,
        );
        Hit::keep_nearer(&mut nearest, crossbar.map(|(t, normal)| Hit { t, albedo: scene.white, normal }));
    }
    for robot in &scene.robots {
        Hit::keep_nearer(&mut nearest, robot_hit(scene, ray, robot.position, robot.jersey));
    }
    if let Some(ball) = scene.ball {
        Hit::keep_nearer(&mut nearest, ball_hit(ray, ball));
    }

    let (mut colour, solid_t) = match nearest {
        Some(hit) => (multiply(hit.albedo, scene.lighting.shade(&hit.normal)), hit.t),
        None => surroundings_or_ground(scene, ray),
    };
    // Every object stands on the ground inside the hall, so a ray meets it before the ground or the
    // hall behind it: the nearest object, when there is one, is what the ray sees.
    if scene.nets {
        colour = through_nets(scene, ray, solid_t, colour);
    }
    colour
}

fn multiply(a: Linear, b: Linear) -> Linear {
    [a[0] * b[0], a[1] * b[1], a[2] * b[2]]
}

fn mix(a: Linear, b: Linear, amount: f64) -> Linear {
    [0, 1, 2].map(|i| a[i] * (1.0 - amount) + b[i] * amount)
}

/// Ground (carpet, lines, floor) or, above the horizon, the hall; with the distance to it.
fn surroundings_or_ground(scene: &Scene, ray: &Ray) -> (Linear, f64) {
    if ray.direction.z < -EPSILON {
        let t = -ray.origin.z / ray.direction.z;
        let hit = ray.at(t);
        let point = Point2::new(hit.x, hit.y);
        if scene.field.is_on_carpet(point) {
            let albedo = ground_albedo(scene, point);
            let light = if scene.shadows {
                let lighting = &scene.lighting;
                let second_lit =
                    lighting.second.is_none_or(|second| !in_shadow(scene, &hit, second.direction));
                lighting.shade_lit(&Vector3::z(), [!in_shadow(scene, &hit, lighting.direction), second_lit])
            } else {
                scene.lighting.shade(&Vector3::z())
            };
            return (multiply(albedo, light), t);
        }
    }
    match scene.surroundings {
        Surroundings::Black => ([0.0; 3], f64::INFINITY),
        Surroundings::Asymmetric { seed } => hall(scene, ray, seed),
    }
}

/// The carpet's or the paint's albedo at a ground point, with texture and wear where the scene has them.
fn ground_albedo(scene: &Scene, point: Point2<f64>) -> Linear {
    let painted = scene.field.is_painted(point);
    let Some(wear) = scene.wear else {
        return if painted { scene.paint } else { scene.carpet };
    };
    // Patches (about a metre) and grain (a few centimetres) of the carpet.
    let texture = 0.7 * value_noise(wear.seed, point, 1.0) + 0.3 * value_noise(wear.seed ^ 1, point, 0.04);
    let carpet = scene.carpet.map(|channel| channel * (1.0 + wear.carpet * texture));
    if !painted {
        return carpet;
    }
    let worn = wear.paint * value_noise(wear.seed ^ 2, point, 0.3).max(0.0);
    mix(scene.paint, carpet, worn)
}

/// Smooth value noise in [−1, 1] with features `scale` metres across.
fn value_noise(seed: u64, point: Point2<f64>, scale: f64) -> f64 {
    let (x, y) = (point.x / scale, point.y / scale);
    let (cell_x, cell_y) = (x.floor(), y.floor());
    let lattice = |i: f64, j: f64| {
        let bits = mix_bits(seed ^ mix_bits((i as i64 as u64) ^ mix_bits(j as i64 as u64)));
        (bits >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    };
    let smooth = |t: f64| t * t * (3.0 - 2.0 * t);
    let (fx, fy) = (smooth(x - cell_x), smooth(y - cell_y));
    let top = lattice(cell_x, cell_y) * (1.0 - fx) + lattice(cell_x + 1.0, cell_y) * fx;
    let bottom = lattice(cell_x, cell_y + 1.0) * (1.0 - fx) + lattice(cell_x + 1.0, cell_y + 1.0) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// Whether a robot, the ball or a goal post stands between a ground point and the light `towards`.
fn in_shadow(scene: &Scene, ground: &Point3<f64>, towards: Vector3<f64>) -> bool {
    let ray = Ray { origin: ground + Vector3::z() * 1e-6, direction: towards };
    scene.robots.iter().any(|robot| robot_hit(scene, &ray, robot.position, robot.jersey).is_some())
        || scene.ball.is_some_and(|ball| ball_hit(&ray, ball).is_some())
        || scene.field.goals.iter().any(|goal| {
            goal.posts
                .iter()
                .any(|post| vertical_cylinder(&ray, *post, goal.post_radius, 0.0, goal.height).is_some())
        })
}

/// The hall around the carpet: grey floor, panelled walls, dark ceiling.
fn hall(scene: &Scene, ray: &Ray, seed: u64) -> (Linear, f64) {
    let dimensions = scene.field.dimensions();
    let half = [dimensions.carpet_half_length() + HALL_MARGIN, dimensions.carpet_half_width() + HALL_MARGIN];
    let ambient = scene.lighting.shade(&Vector3::zeros());
    let mut t_exit = f64::INFINITY;
    let mut wall = None;
    for (axis, half) in half.into_iter().enumerate() {
        let direction = ray.direction[axis];
        if direction.abs() > EPSILON {
            let side = direction.signum();
            let t = (side * half - ray.origin[axis]) / direction;
            if t > 0.0 && t < t_exit {
                t_exit = t;
                wall = Some((axis, side));
            }
        }
    }
    if ray.direction.z < -EPSILON {
        let t = -ray.origin.z / ray.direction.z;
        if t < t_exit {
            return (multiply([0.25, 0.24, 0.22], scene.lighting.shade(&Vector3::z())), t);
        }
    } else if ray.direction.z > EPSILON {
        let t = (HALL_HEIGHT - ray.origin.z) / ray.direction.z;
        if t < t_exit {
            return (multiply([0.08; 3], ambient), t);
        }
    }
    let Some((axis, side)) = wall else { return ([0.0; 3], f64::INFINITY) };
    let hit = ray.at(t_exit);
    let along = hit[1 - axis];
    let column = (along / PANEL_SIZE.0).floor() as i64;
    let row = (hit.z / PANEL_SIZE.1).floor() as i64;
    let wall_id = (axis as u64) * 2 + (side > 0.0) as u64;
    let hash = mix_bits(seed ^ mix_bits(wall_id ^ mix_bits(column as u64 ^ mix_bits(row as u64))));
    (multiply(panel_albedo(hash), ambient), t_exit)
}

/// The albedo of the wall panel with this hash, `panel_colour` remembered: neighbouring rays mostly
/// meet the same panel, so each thread keeps the last one (the conversion takes three `pow`).
fn panel_albedo(hash: u64) -> Linear {
    thread_local! {
        static LAST: Cell<Option<(u64, Linear)>> = const { Cell::new(None) };
    }
    LAST.with(|last| {
        if let Some((key, albedo)) = last.get()
            && key == hash
        {
            return albedo;
        }
        let albedo = panel_colour(hash);
        last.set(Some((hash, albedo)));
        albedo
    })
}

/// A wall panel's colour from its hash: hue, saturation and value from three 16-bit fields.
fn panel_colour(hash: u64) -> Linear {
    let unit = |shift: u32| ((hash >> shift) & 0xffff) as f64 / 65535.0;
    hsv_to_linear(360.0 * unit(0), unit(16), 0.15 + 0.8 * unit(32))
}

/// splitmix64's finaliser: a well-mixed 64-bit hash.
pub(super) fn mix_bits(mut value: u64) -> u64 {
    value = value.wrapping_add(0x9e37_79b9_7f4a_7c15);
    value = (value ^ (value >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    value = (value ^ (value >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    value ^ (value >> 31)
}

/// Blends the nets of both goals that the ray crosses before `solid_t` over `colour`.
fn through_nets(scene: &Scene, ray: &Ray, solid_t: f64, mut colour: Linear) -> Linear {
    let net_colour = multiply(scene.white, scene.lighting.shade(&Vector3::z()));
    for goal in &scene.field.goals {
        let front_x = goal.posts[0].x;
        let (x_low, x_high) = (front_x.min(goal.back_x), front_x.max(goal.back_x));
        let half_width = goal.posts[0].y;
        let inside = |point: &Point3<f64>, x_tolerance: f64| {
            point.x >= x_low - x_tolerance
                && point.x <= x_high + x_tolerance
                && point.y.abs() <= half_width + 1e-9
                && point.z >= 0.0
                && point.z <= goal.height + 1e-9
        };
        let planes = [(0, goal.back_x), (1, half_width), (1, -half_width), (2, goal.height)];
        for (axis, offset) in planes {
            let direction = ray.direction[axis];
            if direction.abs() < EPSILON {
                continue;
            }
            let t = (offset - ray.origin[axis]) / direction;
            if t > EPSILON && t < solid_t && inside(&ray.at(t), 1e-9) {
                colour = mix(colour, net_colour, NET_OPACITY);
            }
        }
    }
    colour
}

/// Nearest intersection of a ray with a vertical cylinder (side and top cap), with the outward normal.
fn vertical_cylinder(
    ray: &Ray,
    centre: Point2<f64>,
    radius: f64,
    bottom: f64,
    top: f64,
) -> Option<(f64, Vector3<f64>)> {
    let (ox, oy) = (ray.origin.x - centre.x, ray.origin.y - centre.y);
    let (dx, dy) = (ray.direction.x, ray.direction.y);
    let a = dx * dx + dy * dy;
    let mut best: Option<(f64, Vector3<f64>)> = None;
    if a > EPSILON {
        let b = ox * dx + oy * dy;
        let c = ox * ox + oy * oy - radius * radius;
        let discriminant = b * b - a * c;
        if discriminant >= 0.0 {
            let t = (-b - discriminant.sqrt()) / a;
            let z = ray.origin.z + t * ray.direction.z;
            if t > EPSILON && z >= bottom && z <= top {
                let normal = Vector3::new(ox + t * dx, oy + t * dy, 0.0) / radius;
                best = Some((t, normal));
            }
        }
    }
    if ray.direction.z < -EPSILON && ray.origin.z > top {
        let t = (top - ray.origin.z) / ray.direction.z;
        let (px, py) = (ox + t * dx, oy + t * dy);
        if px * px + py * py <= radius * radius && best.is_none_or(|(best_t, _)| t < best_t) {
            best = Some((t, Vector3::z()));
        }
    }
    best
}

/// Nearest intersection with the crossbar: a cylinder along y at (x, z) between `y_low` and `y_high`.
fn crossbar(ray: &Ray, x: f64, z: f64, radius: f64, y_low: f64, y_high: f64) -> Option<(f64, Vector3<f64>)> {
    let (ox, oz) = (ray.origin.x - x, ray.origin.z - z);
    let (dx, dz) = (ray.direction.x, ray.direction.z);
    let a = dx * dx + dz * dz;
    if a < EPSILON {
        return None;
    }
    let b = ox * dx + oz * dz;
    let discriminant = b * b - a * (ox * ox + oz * oz - radius * radius);
    if discriminant < 0.0 {
        return None;
    }
    let t = (-b - discriminant.sqrt()) / a;
    let y = ray.origin.y + t * ray.direction.y;
    (t > EPSILON && y >= y_low && y <= y_high)
        .then(|| (t, Vector3::new(ox + t * dx, 0.0, oz + t * dz) / radius))
}

/// Nearest intersection with a sphere, with the outward unit normal.
fn sphere(ray: &Ray, centre: Point3<f64>, radius: f64) -> Option<(f64, Vector3<f64>)> {
    let offset = ray.origin - centre;
    let a = ray.direction.norm_squared();
    let b = offset.dot(&ray.direction);
    let discriminant = b * b - a * (offset.norm_squared() - radius * radius);
    if discriminant < 0.0 {
        return None;
    }
    let t = (-b - discriminant.sqrt()) / a;
    (t > EPSILON).then(|| (t, (ray.at(t) - centre) / radius))
}

fn robot_hit(scene: &Scene, ray: &Ray, position: Point2<f64>, jersey: Linear) -> Option<Hit> {
    if passes_wide_of(ray, position) {
        return None;
    }
    body_hit(scene, ray, position, jersey)
}

/// The nearest of a robot's legs, torso and head along the ray, without the cheap rejection.
fn body_hit(scene: &Scene, ray: &Ray, position: Point2<f64>, jersey: Linear) -> Option<Hit> {
    let mut nearest = None;
    let legs = vertical_cylinder(ray, position, body::LEGS_RADIUS, 0.0, body::LEGS_TOP);
    Hit::keep_nearer(&mut nearest, legs.map(|(t, normal)| Hit { t, albedo: scene.white, normal }));
    let torso = vertical_cylinder(ray, position, body::TORSO_RADIUS, body::LEGS_TOP, body::TORSO_TOP);
    Hit::keep_nearer(&mut nearest, torso.map(|(t, normal)| Hit { t, albedo: jersey, normal }));
    let head = sphere(ray, Point3::new(position.x, position.y, body::HEAD_CENTRE), body::HEAD_RADIUS);
    Hit::keep_nearer(&mut nearest, head.map(|(t, normal)| Hit { t, albedo: scene.white, normal }));
    nearest
}

/// Cheap rejection for a robot standing at `position`: whether the ray stays farther from its axis
/// than the widest part of its body (with a margin), seen from above: it passes wide of the axis, or
/// the robot is behind the ray's origin. Squared comparisons, no root. Near-vertical rays are never
/// rejected.
fn passes_wide_of(ray: &Ray, position: Point2<f64>) -> bool {
    let (to_x, to_y) = (position.x - ray.origin.x, position.y - ray.origin.y);
    let (dx, dy) = (ray.direction.x, ray.direction.y);
    let horizontal_squared = dx * dx + dy * dy;
    if horizontal_squared <= EPSILON {
        return false;
    }
    let reach_squared = (body::TORSO_RADIUS + 0.01).powi(2) * horizontal_squared;
    let across = to_x * dy - to_y * dx;
    let along = to_x * dx + to_y * dy;
    across * across > reach_squared || (along < 0.0 && along * along > reach_squared)
}

fn ball_hit(ray: &Ray, position: Point2<f64>) -> Option<Hit> {
    let (t, normal) = sphere(ray, Point3::new(position.x, position.y, BALL_RADIUS), BALL_RADIUS)?;
    Some(Hit { t, albedo: ball_albedo(&normal), normal })
}

/// A classic ball: 12 black patches centred on the vertices of an icosahedron.
fn ball_albedo(normal: &Vector3<f64>) -> Linear {
    const GOLDEN: f64 = 1.618_033_988_749_895;
    const PATCH_COS: f64 = 0.95; // angular radius ≈ 18°
    let norm = (1.0 + GOLDEN * GOLDEN).sqrt();
    let (a, b) = (1.0 / norm, GOLDEN / norm);
    let (x, y, z) = (normal.x.abs(), normal.y.abs(), normal.z.abs());
    let closest = (a * y + b * z).max(a * x + b * y).max(b * x + a * z);
    if closest > PATCH_COS { [0.03; 3] } else { [0.8; 3] }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::FieldModel;

    fn ray(origin: (f64, f64, f64), direction: (f64, f64, f64)) -> Ray {
        Ray {
            origin: Point3::new(origin.0, origin.1, origin.2),
            direction: Vector3::new(direction.0, direction.1, direction.2),
        }
    }

    #[test]
    fn vertical_cylinder_is_hit_from_the_side() {
        let (t, normal) =
            vertical_cylinder(&ray((0.0, 0.0, 0.5), (1.0, 0.0, 0.0)), Point2::new(2.0, 0.0), 0.1, 0.0, 1.0)
                .unwrap();
        assert!((t - 1.9).abs() < 1e-12);
        assert!((normal - Vector3::new(-1.0, 0.0, 0.0)).norm() < 1e-12);
        assert!(
            vertical_cylinder(&ray((0.0, 0.0, 1.5), (1.0, 0.0, 0.0)), Point2::new(2.0, 0.0), 0.1, 0.0, 1.0)
                .is_none()
        );
    }

    #[test]
    fn ground_shows_carpet_lines_and_black_beyond() {
        let scene = Scene::plain(FieldModel::default());
        let carpet = trace(&scene, &ray((1.0, 1.0, 0.5), (0.0, 0.0, -1.0)));
        let line = trace(&scene, &ray((0.0, 1.0, 0.5), (0.0, 0.0, -1.0)));
        let beyond = trace(&scene, &ray((6.0, 0.0, 0.5), (0.0, 0.0, -1.0)));
        assert!(carpet[1] > carpet[0] && carpet[1] > carpet[2]);
        assert!(line.iter().all(|channel| *channel > 0.7));
        assert_eq!(beyond, [0.0; 3]);
    }

    #[test]
    fn asymmetric_hall_is_not_black() {
        let mut scene = Scene::plain(FieldModel::default());
        scene.surroundings = Surroundings::Asymmetric { seed: 3 };
        let wall = trace(&scene, &ray((0.0, 0.0, 0.5), (1.0, 0.0, 0.1)));
        assert!(wall.iter().any(|channel| *channel > 0.0));
    }

    #[test]
    fn a_panel_keeps_its_own_colour_whatever_panel_came_before() {
        let hashes = [mix_bits(1), mix_bits(2), mix_bits(2), mix_bits(1), mix_bits(3)];
        for hash in hashes {
            assert_eq!(panel_albedo(hash), panel_colour(hash));
        }
        assert_ne!(panel_colour(hashes[0]), panel_colour(hashes[1]));
    }

    #[test]
    fn rays_passed_over_as_wide_of_a_robot_miss_it() {
        let scene = Scene::plain(FieldModel::default());
        let robot = Point2::new(1.0, -0.5);
        let (mut rejected, mut hits) = (0, 0);
        for origin in [(0.0, 0.0, 0.5), (1.3, -0.4, 0.45), (2.5, 1.0, 0.05), (1.0, -0.5, 1.0)] {
            for i in 0..90 {
                for j in 0..30 {
                    let azimuth = f64::from(i) * std::f64::consts::TAU / 90.0;
                    let elevation = f64::from(j - 20) * 0.04;
                    let ray = ray(origin, (azimuth.cos(), azimuth.sin(), elevation));
                    let hit = robot_hit(&scene, &ray, robot, [0.5; 3]).is_some();
                    if passes_wide_of(&ray, robot) {
                        rejected += 1;
                        // Without the rejection, the body itself is missed too.
                        let body = body_hit(&scene, &ray, robot, [0.5; 3]);
                        assert!(body.is_none(), "{origin:?} {azimuth} {elevation}");
                    }
                    hits += usize::from(hit);
                }
            }
        }
        assert!(rejected > 5000 && hits > 50, "{rejected} {hits}");
    }

    #[test]
    fn robot_occludes_the_line_behind_it() {
        let mut scene = Scene::plain(FieldModel::default());
        let through = ray((-2.0, 0.0, 0.8), (2.0, 0.0, -0.8));
        assert!(trace(&scene, &through).iter().all(|channel| *channel > 0.7), "the centre line is visible");
        scene
            .robots
            .push(super::super::scene::Robot { position: Point2::new(-1.0, 0.0), jersey: [0.6, 0.0, 0.0] });
        let seen = trace(&scene, &through);
        assert!(seen[0] > seen[1] * 3.0, "the red jersey hides the line: {seen:?}");
    }
}
