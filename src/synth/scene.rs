//! The synthetic room: a closed box of planes (floor, ceiling, four walls made of thin
//! cuboids) with furniture inside, as a list of parry3d cuboids. Ray casting gives exact
//! depth, hit points and normals; surfaces are sampled uniformly by area for the map cloud;
//! a small procedural shader gives the camera image its look.
//!
//! Map frame: x east, y north, z up, the room spanning `[0, L] × [0, W] × [0, H]`.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d::math::{Pose, Rot3, Vector};
use parry3d::query::{PointQuery, Ray, RayCast};
use parry3d::shape::Cuboid;
use rand::rngs::StdRng;
use rand::RngExt;

use crate::rng::mix64;

mod building;
pub use building::BuildingLayout;

/// How a surface is textured in the camera image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Texture {
    /// Floor tiles with grout lines.
    Tiles,
    /// Wallpaper with vertical stripes and speckles.
    Wallpaper,
    /// Wood grain.
    Wood,
    /// Fabric-like fine noise.
    Fabric,
    /// A "painting": large coloured blobs.
    Painting,
}

/// One solid of the scene.
#[derive(Clone, Debug)]
pub struct Solid {
    pub name: &'static str,
    pub cuboid: Cuboid,
    pub pose: Pose,
    /// Linear RGB albedo in [0, 1].
    pub albedo: [f64; 3],
    pub texture: Texture,
}

/// A ray hit: distance along the (unnormalised) ray direction, the solid and its normal.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub toi: f64,
    pub solid: usize,
    pub normal: Vector3<f64>,
}

/// The room and its furniture.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Interior size (L, W, H), metres.
    pub size: Vector3<f64>,
    pub solids: Vec<Solid>,
    /// Point light (for shading only).
    pub light: Point3<f64>,
    /// Seed of the procedural textures.
    pub texture_seed: u64,
}

fn v3(x: f64, y: f64, z: f64) -> Vector {
    Vector::new(x as f32, y as f32, z as f32)
}

fn to_na(v: Vector) -> Vector3<f64> {
    Vector3::new(v.x as f64, v.y as f64, v.z as f64)
}

/// Builds a cuboid solid from its centre, half extents and yaw (about +z).
fn solid(name: &'static str, centre: [f64; 3], half: [f64; 3], yaw: f64, albedo: [f64; 3], texture: Texture) -> Solid {
    let rotation = Rot3::from_axis_angle(v3(0.0, 0.0, 1.0), yaw as f32);
    Solid {
        name,
        cuboid: Cuboid::new(v3(half[0], half[1], half[2])),
        pose: Pose::from_parts(v3(centre[0], centre[1], centre[2]), rotation),
        albedo,
        texture,
    }
}

/// Wall thickness, m.
const WALL_THICKNESS: f64 = 0.1;

/// A room's interior extents (m) and the horizontal scale of a furniture layout made for 5 × 4 m.
struct RoomSize {
    l: f64,
    w: f64,
    h: f64,
    sx: f64,
    sy: f64,
}

/// A colour varied by a random brightness of ±15 %.
fn jitter(rng: &mut StdRng, c: [f64; 3]) -> [f64; 3] {
    let k = 0.85 + 0.3 * rng.random::<f64>();
    [(c[0] * k).clamp(0.02, 1.0), (c[1] * k).clamp(0.02, 1.0), (c[2] * k).clamp(0.02, 1.0)]
}

/// Floor, ceiling and the four walls.
fn shell(room: &RoomSize, rng: &mut StdRng) -> Vec<Solid> {
    box_shell([room.l, room.w, room.h], WALL_THICKNESS, |albedo| jitter(rng, albedo))
}

/// Floor, ceiling and the four walls of a box of interior `[l, w, h]` with walls `t` thick;
/// `colour` turns each surface's base albedo into its own (called floor, ceiling, then the
/// west, east, south and north walls).
pub(super) fn box_shell([l, w, h]: [f64; 3], t: f64, mut colour: impl FnMut([f64; 3]) -> [f64; 3]) -> Vec<Solid> {
    vec![
        solid(
            "floor",
            [l / 2.0, w / 2.0, -t / 2.0],
            [l / 2.0 + t, w / 2.0 + t, t / 2.0],
            0.0,
            colour([0.55, 0.45, 0.35]),
            Texture::Tiles,
        ),
        solid(
            "ceiling",
            [l / 2.0, w / 2.0, h + t / 2.0],
            [l / 2.0 + t, w / 2.0 + t, t / 2.0],
            0.0,
            colour([0.85, 0.85, 0.82]),
            Texture::Fabric,
        ),
        solid(
            "wall_west",
            [-t / 2.0, w / 2.0, h / 2.0],
            [t / 2.0, w / 2.0 + t, h / 2.0 + t],
            0.0,
            colour([0.75, 0.70, 0.55]),
            Texture::Wallpaper,
        ),
        solid(
            "wall_east",
            [l + t / 2.0, w / 2.0, h / 2.0],
            [t / 2.0, w / 2.0 + t, h / 2.0 + t],
            0.0,
            colour([0.55, 0.65, 0.75]),
            Texture::Wallpaper,
        ),
        solid(
            "wall_south",
            [l / 2.0, -t / 2.0, h / 2.0],
            [l / 2.0 + t, t / 2.0, h / 2.0 + t],
            0.0,
            colour([0.70, 0.75, 0.60]),
            Texture::Wallpaper,
        ),
        solid(
            "wall_north",
            [l / 2.0, w + t / 2.0, h / 2.0],
            [l / 2.0 + t, t / 2.0, h / 2.0 + t],
            0.0,
            colour([0.78, 0.62, 0.58]),
            Texture::Wallpaper,
        ),
    ]
}

/// The table, its legs and the box on it (kept ≥ ~0.8 m from the camera path, as all furniture).
fn table(room: &RoomSize, rng: &mut StdRng) -> Vec<Solid> {
    let (sx, sy) = (room.sx, room.sy);
    let mut solids = Vec::new();
    let wood = jitter(rng, [0.55, 0.35, 0.2]);
    let table = (1.0 * sx, 3.25 * sy);
    solids.push(solid("table_top", [table.0, table.1, 0.74], [0.6, 0.38, 0.02], 0.0, wood, Texture::Wood));
    for (dx, dy) in [(-0.55, -0.33), (0.55, -0.33), (-0.55, 0.33), (0.55, 0.33)] {
        solids.push(solid(
            "table_leg",
            [table.0 + dx, table.1 + dy, 0.36],
            [0.03, 0.03, 0.36],
            0.0,
            wood,
            Texture::Wood,
        ));
    }
    solids.push(solid(
        "box_on_table",
        [table.0 + 0.2, table.1 + 0.05, 0.86],
        [0.15, 0.1, 0.1],
        0.35,
        jitter(rng, [0.8, 0.2, 0.15]),
        Texture::Fabric,
    ));
    solids
}

/// The rest of the furniture and what hangs on the walls.
fn furnishings(room: &RoomSize, rng: &mut StdRng) -> Vec<Solid> {
    let (l, w, h, sx, sy) = (room.l, room.w, room.h, room.sx, room.sy);
    vec![
        solid(
            "cabinet",
            [l - 0.26, 0.55 * sy, 0.9],
            [0.25, 0.45, 0.9],
            0.0,
            jitter(rng, [0.35, 0.3, 0.28]),
            Texture::Wood,
        ),
        solid(
            "sofa_seat",
            [2.5 * sx, 0.42, 0.22],
            [0.9, 0.4, 0.22],
            0.0,
            jitter(rng, [0.25, 0.35, 0.6]),
            Texture::Fabric,
        ),
        solid(
            "sofa_back",
            [2.5 * sx, 0.1, 0.5],
            [0.9, 0.1, 0.5],
            0.0,
            jitter(rng, [0.22, 0.32, 0.55]),
            Texture::Fabric,
        ),
        solid(
            "armchair",
            [0.6 * sx, 0.8 * sy, 0.3],
            [0.3, 0.3, 0.3],
            0.5,
            jitter(rng, [0.6, 0.25, 0.3]),
            Texture::Fabric,
        ),
        solid("shelf", [4.45 * sx, 3.45 * sy, 0.7], [0.4, 0.2, 0.7], -0.6, jitter(rng, [0.5, 0.4, 0.3]), Texture::Wood),
        solid(
            "bed",
            [3.0 * sx, 3.62 * sy, 0.25],
            [0.6, 0.35, 0.25],
            0.1,
            jitter(rng, [0.7, 0.7, 0.75]),
            Texture::Fabric,
        ),
        solid(
            "pillar",
            [0.3, 2.0 * sy, h / 2.0],
            [0.15, 0.15, h / 2.0],
            0.0,
            jitter(rng, [0.8, 0.8, 0.8]),
            Texture::Fabric,
        ),
        solid(
            "painting",
            [2.6 * sx, w - 0.01, 1.5],
            [0.5, 0.012, 0.35],
            0.0,
            jitter(rng, [0.9, 0.8, 0.6]),
            Texture::Painting,
        ),
        solid("door", [0.012, 3.1 * sy, 1.0], [0.012, 0.45, 1.0], 0.0, jitter(rng, [0.6, 0.45, 0.3]), Texture::Wood),
        solid(
            "poster",
            [l - 0.01, 2.4 * sy, 1.6],
            [0.012, 0.4, 0.5],
            0.0,
            jitter(rng, [0.8, 0.85, 0.9]),
            Texture::Painting,
        ),
    ]
}

/// Name prefix of the solids that repeat identically along a row (see [`Scene::office`]).
const REPEATED: &str = "cubicle";

/// Two rows of identical cubicles (desk, pedestal, monitor, side partition, chair) along the
/// long walls, one every `period` metres, the second row the first mirrored across the room.
fn cubicle_rows(room: &RoomSize, period: f64) -> Vec<Solid> {
    let (l, w) = (room.l, room.w);
    let count = ((l - 1.2) / period).floor().max(1.0) as usize;
    let first = (l - (count - 1) as f64 * period) / 2.0;
    // (name, centre offset from the cubicle's wall point, half extents), for the row at y = 0.
    let parts: [(&'static str, [f64; 3], [f64; 3]); 6] = [
        ("cubicle_desk", [0.0, 0.45, 0.74], [0.6, 0.35, 0.02]),
        ("cubicle_pedestal", [0.4, 0.45, 0.35], [0.18, 0.3, 0.35]),
        ("cubicle_monitor", [0.0, 0.3, 0.98], [0.25, 0.02, 0.18]),
        ("cubicle_partition", [-0.72, 0.6, 0.65], [0.03, 0.6, 0.65]),
        ("cubicle_chair_seat", [0.0, 1.15, 0.46], [0.24, 0.24, 0.04]),
        ("cubicle_chair_back", [0.0, 1.4, 0.75], [0.22, 0.03, 0.28]),
    ];
    let colour = |name: &str| match name {
        "cubicle_chair_seat" | "cubicle_chair_back" => ([0.15, 0.15, 0.18], Texture::Fabric),
        "cubicle_partition" => ([0.55, 0.58, 0.62], Texture::Fabric),
        "cubicle_monitor" => ([0.08, 0.08, 0.08], Texture::Fabric),
        _ => ([0.7, 0.66, 0.58], Texture::Wood),
    };
    let mut solids = Vec::with_capacity(2 * count * parts.len());
    for k in 0..count {
        let x = first + k as f64 * period;
        for (name, [dx, dy, z], half) in parts {
            let (albedo, texture) = colour(name);
            solids.push(solid(name, [x + dx, dy, z], half, 0.0, albedo, texture));
            solids.push(solid(name, [x - dx, w - dy, z], half, 0.0, albedo, texture));
        }
    }
    solids
}

impl Scene {
    /// An open-plan office of interior size `size`: the room's shell and two rows of identical
    /// cubicles, one every `period` metres along x (its long side).
    pub fn office(size: Vector3<f64>, period: f64, rng: &mut StdRng) -> Scene {
        let (l, w, h) = (size.x.max(3.0), size.y.max(3.0), size.z.max(2.0));
        let room = RoomSize { l, w, h, sx: l / 5.0, sy: w / 4.0 };
        let mut solids = shell(&room, rng);
        solids.extend(cubicle_rows(&room, period.max(1.5)));
        let texture_seed = rng.random::<u64>();
        Scene { size: Vector3::new(l, w, h), solids, light: Point3::new(l / 2.0, w / 2.0, h - 0.3), texture_seed }
    }

    /// Whether `hit` is on a solid that repeats identically along x (an office's cubicles).
    pub fn is_repeated(&self, hit: &Hit) -> bool {
        self.solids.get(hit.solid).is_some_and(|s| s.name.starts_with(REPEATED))
    }

    /// A furnished room of interior size `size` (defaults ≈ 5 × 4 × 2.7 m). Furniture is
    /// laid out for the default room and scaled horizontally with it; `rng` jitters colours.
    pub fn room(size: Vector3<f64>, rng: &mut StdRng) -> Scene {
        let (l, w, h) = (size.x.max(2.0), size.y.max(2.0), size.z.max(1.5));
        let room = RoomSize { l, w, h, sx: l / 5.0, sy: w / 4.0 };
        let mut solids = shell(&room, rng);
        solids.extend(table(&room, rng));
        solids.extend(furnishings(&room, rng));
        let texture_seed = rng.random::<u64>();
        Scene { size: Vector3::new(l, w, h), solids, light: Point3::new(l / 2.0, w / 2.0, h - 0.3), texture_seed }
    }

    /// The nearest hit of the ray `origin + toi · dir` (dir need not be unit).
    pub fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let ray = Ray::new(v3(origin.x, origin.y, origin.z), v3(dir.x, dir.y, dir.z));
        let mut best: Option<Hit> = None;
        for (i, s) in self.solids.iter().enumerate() {
            let max = best.map_or(f32::MAX, |b| b.toi as f32);
            if let Some(hit) = s.cuboid.cast_ray_and_get_normal(&s.pose, &ray, max, true) {
                let toi = hit.time_of_impact as f64;
                if toi > 0.0 && best.is_none_or(|b| toi < b.toi) {
                    best = Some(Hit { toi, solid: i, normal: to_na(hit.normal) });
                }
            }
        }
        best
    }

    /// Distance from a point to the nearest surface (0 inside a solid).
    pub fn distance_to_surfaces(&self, p: &Point3<f64>) -> f64 {
        let q = v3(p.x, p.y, p.z);
        self.solids.iter().map(|s| s.cuboid.distance_to_point(&s.pose, q, true) as f64).fold(f64::INFINITY, f64::min)
    }

    /// Whether a point lies inside the room's interior and outside all solids.
    pub fn is_free(&self, p: &Point3<f64>) -> bool {
        let inside_room =
            p.x > 0.0 && p.y > 0.0 && p.z > 0.0 && p.x < self.size.x && p.y < self.size.y && p.z < self.size.z;
        let q = v3(p.x, p.y, p.z);
        inside_room && !self.solids.iter().any(|s| s.cuboid.contains_point(&s.pose, q))
    }

    /// All six faces of every solid.
    fn faces(&self) -> Vec<Face> {
        let mut faces = Vec::new();
        for s in &self.solids {
            let h = to_na(s.cuboid.half_extents);
            let rot = quat_to_na(s.pose.rotation);
            let centre = to_na(s.pose.translation);
            for axis in 0..3 {
                for sign in [-1.0, 1.0] {
                    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
                    let mut n = Vector3::zeros();
                    n[axis] = sign;
                    let mut c = Vector3::zeros();
                    c[axis] = sign * h[axis];
                    let mut ea = Vector3::zeros();
                    ea[a] = h[a];
                    let mut eb = Vector3::zeros();
                    eb[b] = h[b];
                    faces.push(Face {
                        centre: Point3::from(centre + rot * c),
                        normal: rot * n,
                        ea: rot * ea,
                        eb: rot * eb,
                        area: 4.0 * h[a] * h[b],
                    });
                }
            }
        }
        faces
    }

    /// Points sampled uniformly by area on all visible surfaces, `density` per m².
    pub fn sample_surfaces(&self, density: f64, rng: &mut StdRng) -> Vec<Point3<f64>> {
        let mut out = Vec::new();
        for f in self.faces() {
            let expected = f.area * density.max(0.0);
            let n = expected.floor() as usize + usize::from(rng.random::<f64>() < expected.fract());
            for _ in 0..n {
                let a = 2.0 * rng.random::<f64>() - 1.0;
                let b = 2.0 * rng.random::<f64>() - 1.0;
                let p = f.centre + f.ea * a + f.eb * b;
                // Keep it only if just in front of the face is free space (visible surface).
                if self.is_free(&(p + f.normal * 2e-3)) {
                    out.push(p);
                }
            }
        }
        out
    }

    /// Linear RGB of a surface point seen from `eye`.
    pub fn shade(&self, hit_point: &Point3<f64>, hit: &Hit, eye: &Point3<f64>) -> [f64; 3] {
        let Some(s) = self.solids.get(hit.solid) else { return [0.0; 3] };
        let n = hit.normal;
        let to_light = self.light - hit_point;
        let dist2 = to_light.norm_squared().max(1e-6);
        let lambert = (n.dot(&to_light) / dist2.sqrt()).max(0.0);
        let view = (eye - hit_point).normalize();
        let facing = n.dot(&view).abs();
        let light = 0.3 + 0.55 * lambert * (6.0 / (4.0 + dist2)) + 0.15 * facing;
        // Texture coordinates: in the solid's local frame, the two axes spanning the face.
        let local = s.pose.inverse_transform_point(v3(hit_point.x, hit_point.y, hit_point.z));
        let local = to_na(local);
        let ln = quat_to_na(s.pose.rotation).inverse() * n;
        let axis = (0..3).max_by(|&i, &j| ln[i].abs().total_cmp(&ln[j].abs())).unwrap_or(2);
        let (ua, ub) = ((axis + 1) % 3, (axis + 2) % 3);
        // Keep "vertical" as the second texture axis on walls.
        let (u, v) = if ua == 2 { (local[ub], local[ua]) } else { (local[ua], local[ub]) };
        let seed = self.texture_seed ^ (hit.solid as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let tex = texture(s.texture, u, v, seed);
        let mut rgb = [0.0; 3];
        for (c, out) in rgb.iter_mut().enumerate() {
            *out = (s.albedo[c] * tex[c] * light).clamp(0.0, 1.0);
        }
        rgb
    }
}

struct Face {
    centre: Point3<f64>,
    normal: Vector3<f64>,
    ea: Vector3<f64>,
    eb: Vector3<f64>,
    area: f64,
}

fn quat_to_na(q: Rot3) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w as f64, q.x as f64, q.y as f64, q.z as f64))
}

/// A pose as a parry pose (f32).
#[allow(dead_code)]
pub fn to_parry_pose(iso: &Isometry3<f64>) -> Pose {
    let q = iso.rotation.quaternion();
    let t: &Translation3<f64> = &iso.translation;
    Pose::from_parts(v3(t.x, t.y, t.z), Rot3::from_xyzw(q.i as f32, q.j as f32, q.k as f32, q.w as f32).normalize())
}

fn lattice(ix: i64, iy: i64, seed: u64) -> f64 {
    let h = mix64(
        seed ^ mix64((ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)),
    );
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth 2D value noise in [0, 1].
fn value_noise(x: f64, y: f64, seed: u64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let (ix, iy) = (x0 as i64, y0 as i64);
    let a = lattice(ix, iy, seed);
    let b = lattice(ix + 1, iy, seed);
    let c = lattice(ix, iy + 1, seed);
    let d = lattice(ix + 1, iy + 1, seed);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// Fractal noise in [0, 1].
fn fbm(x: f64, y: f64, octaves: u32, seed: u64) -> f64 {
    let (mut sum, mut amp, mut freq, mut norm) = (0.0, 1.0, 1.0, 0.0);
    for o in 0..octaves {
        sum += amp * value_noise(x * freq, y * freq, seed.wrapping_add(o as u64));
        norm += amp;
        amp *= 0.5;
        freq *= 2.0;
    }
    sum / norm.max(1e-9)
}

/// Multiplicative texture (per channel, around 1) at surface coordinates (u, v) in metres.
fn texture(kind: Texture, u: f64, v: f64, seed: u64) -> [f64; 3] {
    let g = |x: f64| [x, x, x];
    match kind {
        Texture::Tiles => {
            let size = 0.5;
            let (fu, fv) = ((u / size).rem_euclid(1.0), (v / size).rem_euclid(1.0));
            let grout = fu < 0.03 || fv < 0.03;
            let tile = lattice((u / size).floor() as i64, (v / size).floor() as i64, seed);
            let speck = fbm(u * 12.0, v * 12.0, 3, seed ^ 1);
            if grout {
                g(0.35)
            } else {
                g(0.75 + 0.25 * tile + 0.3 * (speck - 0.5))
            }
        }
        Texture::Wallpaper => {
            let stripe = if (u / 0.12).rem_euclid(1.0) < 0.5 { 1.0 } else { 0.82 };
            let speck = fbm(u * 8.0, v * 8.0, 4, seed);
            g(stripe * (0.8 + 0.4 * speck))
        }
        Texture::Wood => {
            let warp = fbm(u * 2.0, v * 2.0, 3, seed);
            let rings = 0.5 + 0.5 * (40.0 * u + 6.0 * warp).sin();
            let grain = fbm(u * 30.0, v * 3.0, 2, seed ^ 7);
            let k = 0.7 + 0.25 * rings + 0.2 * (grain - 0.5);
            [k, k * 0.95, k * 0.9]
        }
        Texture::Fabric => {
            let n = fbm(u * 15.0, v * 15.0, 4, seed);
            let weave = 0.95 + 0.05 * ((u * 300.0).sin() * (v * 300.0).sin());
            g((0.7 + 0.6 * (n - 0.5)) * weave + 0.3 * (fbm(u * 3.0, v * 3.0, 2, seed ^ 3) - 0.5))
        }
        Texture::Painting => {
            let r = fbm(u * 4.0, v * 4.0, 4, seed);
            let gch = fbm(u * 4.0 + 17.0, v * 4.0, 4, seed ^ 11);
            let b = fbm(u * 4.0, v * 4.0 + 31.0, 4, seed ^ 13);
            [0.3 + 1.2 * r, 0.3 + 1.2 * gch, 0.3 + 1.2 * b]
        }
    }
}
