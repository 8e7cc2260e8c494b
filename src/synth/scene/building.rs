//! A building: two rows of furnished rooms joined by doorways, a route through all of them, a
//! map of any density sampled in parallel, and a ray cast that only tries the solids in view
//! (a building has hundreds; a frame's pixels would otherwise test every one).

use nalgebra::{Isometry3, Point3, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

use super::{mix64, quat_to_na, solid, to_na, v3, Face, Hit, Scene, Solid, Texture};
use crate::geometry::Intrinsics;

/// Doorway width and height, metres.
const DOOR_WIDTH: f64 = 1.2;
const DOOR_HEIGHT: f64 = 2.1;
const WALL: f64 = 0.1;
/// The route turns from one row to the other this far west of the end rooms' centres (clear
/// of their furniture).
const TURN_OFFSET: f64 = 1.2;

/// Where the route through a building runs: a loop at the rows' middle lines, crossing between
/// the rows at `turn_x`.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildingLayout {
    pub rooms_per_row: usize,
    pub room: Vector3<f64>,
}

impl BuildingLayout {
    /// The two x at which the route crosses from one row to the other.
    pub fn turn_x(&self) -> [f64; 2] {
        let l = self.room.x;
        [0.5 * l - TURN_OFFSET, (self.rooms_per_row as f64 - 0.5) * l - TURN_OFFSET]
    }

    /// The corners of the route's loop (at height `z`), in order.
    pub fn route(&self, z: f64) -> Vec<Point3<f64>> {
        let [xa, xb] = self.turn_x();
        let w = self.room.y;
        vec![
            Point3::new(xa, 0.5 * w, z),
            Point3::new(xb, 0.5 * w, z),
            Point3::new(xb, 1.5 * w, z),
            Point3::new(xa, 1.5 * w, z),
        ]
    }
}

impl Scene {
    /// Two rows of `layout.rooms_per_row` rooms (each furnished as [`Scene::room`], the second
    /// row mirrored), doorways in every wall the route crosses.
    pub fn building(layout: &BuildingLayout, rng: &mut StdRng) -> Scene {
        let (n, room) = (layout.rooms_per_row.max(1), layout.room);
        let (l, w, h) = (room.x, room.y, room.z);
        let size = Vector3::new(n as f64 * l, 2.0 * w, h);
        let mut solids = shell(&size);
        solids.extend(walls_with_doors(layout));
        let mut texture_seed = 0;
        for row in 0..2 {
            for col in 0..n {
                let furnished = Scene::room(room, rng);
                texture_seed = furnished.texture_seed;
                let offset = Vector3::new(col as f64 * l, row as f64 * w, 0.0);
                for s in furnished.solids.into_iter().filter(|s| is_furniture(s.name)) {
                    solids.push(placed(&s, &offset, row == 1, w));
                }
            }
        }
        Scene { size, solids, light: Point3::new(size.x / 2.0, size.y / 2.0, h - 0.3), texture_seed }
    }

    /// The solids a camera at `pose` may see (bounding sphere in front of it and within its
    /// field of view, with margin), nearest first.
    pub fn solids_in_view(&self, pose: &Isometry3<f64>, intrinsics: &Intrinsics) -> Vec<SolidInView> {
        let to_cam = pose.inverse();
        // Half-angles of the view, widened a little.
        let tan_x = (intrinsics.cx.max(intrinsics.width as f64 - intrinsics.cx) / intrinsics.fx) * 1.05;
        let tan_y = (intrinsics.cy.max(intrinsics.height as f64 - intrinsics.cy) / intrinsics.fy) * 1.05;
        let (nx, ny) = (1.0 / (1.0 + tan_x * tan_x).sqrt(), 1.0 / (1.0 + tan_y * tan_y).sqrt());
        let mut in_view: Vec<SolidInView> = (0..self.solids.len())
            .filter_map(|i| {
                let s = &self.solids[i];
                let r = to_na(s.cuboid.half_extents).norm() + 0.05;
                let c = to_cam * Point3::from(to_na(s.pose.translation));
                // Inside each side plane through the camera, by at most -r.
                let seen = c.z > -r && (c.z * tan_x - c.x.abs()) * nx > -r && (c.z * tan_y - c.y.abs()) * ny > -r;
                seen.then(|| SolidInView { index: i, nearest_m: c.coords.norm() - r })
            })
            .collect();
        in_view.sort_by(|a, b| a.nearest_m.total_cmp(&b.nearest_m).then(a.index.cmp(&b.index)));
        in_view
    }

    /// The nearest hit among `candidates` ([`Scene::solids_in_view`] from `origin`): once a hit
    /// is nearer than the next candidate can be, the rest are skipped.
    pub fn cast_among(&self, origin: &Point3<f64>, dir: &Vector3<f64>, candidates: &[SolidInView]) -> Option<Hit> {
        let ray = parry3d::query::Ray::new(v3(origin.x, origin.y, origin.z), v3(dir.x, dir.y, dir.z));
        let length = dir.norm();
        let mut best: Option<Hit> = None;
        for c in candidates {
            if best.is_some_and(|b| b.toi * length < c.nearest_m) {
                break;
            }
            let i = c.index;
            let Some(s) = self.solids.get(i) else { continue };
            let max = best.map_or(f32::MAX, |b| b.toi as f32);
            if let Some(hit) = parry3d::query::RayCast::cast_ray_and_get_normal(&s.cuboid, &s.pose, &ray, max, true) {
                let toi = hit.time_of_impact as f64;
                if toi > 0.0 && best.is_none_or(|b| toi < b.toi) {
                    best = Some(Hit { toi, solid: i, normal: to_na(hit.normal) });
                }
            }
        }
        best
    }

    /// About `density` points per m² on every visible surface, sampled face by face in
    /// parallel (each face with its own generator, so the result does not depend on threads),
    /// with Gaussian noise `noise_m`. Each point is checked only against the solids near its face.
    pub fn sample_surfaces_parallel(&self, density: f64, noise_m: f64, seed: u64) -> Vec<Point3<f32>> {
        let faces = self.faces();
        let per_face: Vec<Vec<Point3<f32>>> = faces
            .par_iter()
            .enumerate()
            .map(|(i, f)| self.sample_face(f, density, noise_m, mix64(seed ^ mix64(i as u64 + 1))))
            .collect();
        per_face.concat()
    }

    fn sample_face(&self, f: &Face, density: f64, noise_m: f64, seed: u64) -> Vec<Point3<f32>> {
        let mut rng = StdRng::seed_from_u64(seed);
        let near = self.solids_near(f);
        let expected = f.area * density.max(0.0);
        let n = expected.floor() as usize + usize::from(rng.random::<f64>() < expected.fract());
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let (a, b) = (2.0 * rng.random::<f64>() - 1.0, 2.0 * rng.random::<f64>() - 1.0);
            let p = f.centre + f.ea * a + f.eb * b;
            if !self.is_free_among(&(p + f.normal * 2e-3), &near) {
                continue;
            }
            let jitter = Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * noise_m;
            let q = p + jitter;
            out.push(Point3::new(q.x as f32, q.y as f32, q.z as f32));
        }
        out
    }

    /// Solids whose bounding sphere comes within 1 cm of the face's.
    fn solids_near(&self, f: &Face) -> Vec<usize> {
        let face_r = (f.ea + f.eb).norm().max((f.ea - f.eb).norm()) + 0.01;
        (0..self.solids.len())
            .filter(|&i| {
                let s = &self.solids[i];
                let r = to_na(s.cuboid.half_extents).norm();
                (Point3::from(to_na(s.pose.translation)) - f.centre).norm() <= r + face_r
            })
            .collect()
    }

    fn is_free_among(&self, p: &Point3<f64>, near: &[usize]) -> bool {
        let inside = p.x > 0.0 && p.y > 0.0 && p.z > 0.0 && p.x < self.size.x && p.y < self.size.y && p.z < self.size.z;
        let q = v3(p.x, p.y, p.z);
        inside
            && !near.iter().any(|&i| {
                let s = &self.solids[i];
                parry3d::query::PointQuery::contains_point(&s.cuboid, &s.pose, q)
            })
    }

    /// Area of all faces (visible or not), m².
    pub fn face_area(&self) -> f64 {
        self.faces().iter().map(|f| f.area).sum()
    }
}

/// A solid a camera may see, and how near to the camera any of it can be.
#[derive(Clone, Copy, Debug)]
pub struct SolidInView {
    pub index: usize,
    pub nearest_m: f64,
}

/// A standard normal deviate (Box–Muller).
fn gauss(rng: &mut StdRng) -> f64 {
    let u = rng.random::<f64>().max(1e-300);
    let v = rng.random::<f64>();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// The room pieces a building keeps (its own floor, ceiling and walls replace the rest; the
/// pillar and the wall-hung door and poster would stand in doorways).
fn is_furniture(name: &str) -> bool {
    !(name == "floor" || name == "ceiling" || name.starts_with("wall_") || matches!(name, "pillar" | "poster" | "door"))
}

/// `s` moved by `offset`, mirrored across the room's middle line (y ↦ w − y) when `mirror`.
fn placed(s: &Solid, offset: &Vector3<f64>, mirror: bool, w: f64) -> Solid {
    let c = to_na(s.pose.translation);
    let (_, _, yaw) = quat_to_na(s.pose.rotation).euler_angles();
    let (y, yaw) = if mirror { (w - c.y, -yaw) } else { (c.y, yaw) };
    let half = to_na(s.cuboid.half_extents);
    solid(s.name, [c.x + offset.x, y + offset.y, c.z + offset.z], [half.x, half.y, half.z], yaw, s.albedo, s.texture)
}

/// Floor, ceiling and the four outer walls of a building of interior `size` (untinted).
fn shell(size: &Vector3<f64>) -> Vec<Solid> {
    super::box_shell([size.x, size.y, size.z], WALL, |albedo| albedo)
}

/// The inner walls: between neighbouring rooms of a row (a doorway on the row's middle line)
/// and between the rows (doorways where the route turns).
fn walls_with_doors(layout: &BuildingLayout) -> Vec<Solid> {
    let (n, l, w, h) = (layout.rooms_per_row.max(1), layout.room.x, layout.room.y, layout.room.z);
    let mut walls = Vec::new();
    for col in 1..n {
        let x = col as f64 * l;
        for row in 0..2 {
            let y0 = row as f64 * w;
            walls.extend(wall_span(Axis::Y, x, y0, y0 + w, &[y0 + 0.5 * w], h));
        }
    }
    walls.extend(wall_span(Axis::X, w, 0.0, n as f64 * l, &layout.turn_x(), h));
    walls
}

#[derive(Clone, Copy)]
enum Axis {
    /// A wall along x at y = `at`.
    X,
    /// A wall along y at x = `at`.
    Y,
}

/// A wall from `from` to `to` along `axis` at `at`, with a doorway centred on each of `doors`.
fn wall_span(axis: Axis, at: f64, from: f64, to: f64, doors: &[f64], h: f64) -> Vec<Solid> {
    let mut pieces = Vec::new();
    let mut piece = |a: f64, b: f64, z0: f64, z1: f64| {
        if b - a < 1e-3 || z1 - z0 < 1e-3 {
            return;
        }
        let (mid, half, zc, zh) = ((a + b) / 2.0, (b - a) / 2.0, (z0 + z1) / 2.0, (z1 - z0) / 2.0);
        let (centre, extent) = match axis {
            Axis::X => ([mid, at, zc], [half, WALL / 2.0, zh]),
            Axis::Y => ([at, mid, zc], [WALL / 2.0, half, zh]),
        };
        pieces.push(solid("wall_inner", centre, extent, 0.0, [0.8, 0.78, 0.7], Texture::Wallpaper));
    };
    let mut start = from;
    let mut sorted = doors.to_vec();
    sorted.sort_by(f64::total_cmp);
    for d in sorted {
        let (a, b) = (d - DOOR_WIDTH / 2.0, d + DOOR_WIDTH / 2.0);
        piece(start, a, 0.0, h);
        piece(a, b, DOOR_HEIGHT, h);
        start = b;
    }
    piece(start, to, 0.0, h);
    pieces
}
