//! Ray casting of a [`Scene`]: colour (supersampled, so the ground truth has no
//! aliasing of its own) and metric depth along the optical axis (pixel centre,
//! `+inf` for sky) for any pose and intrinsics. Deterministic; parallel over
//! rows. Camera convention as in `crate::synth` and `crate::capture::export`: at
//! roll = yaw = 0 and pitch φ the optical axis is `(sin φ, 0, −cos φ)`, the image
//! columns run along `(cos φ, 0, sin φ)` and the rows along `(0, −1, 0)`; roll, pitch
//! and yaw turn that frame as an autopilot's attitude turns its body (world x north,
//! y west, z up).
//! Invariant: [`render`] finds the same nearest surface, with the same depth
//! bits, as [`trace`] over the whole scene ([`render_reference`] is that).

mod bins;

use crate::core::{DepthData, DepthImage, Intrinsics};
use crate::scene::{Scene, Texture};
use bins::Bins;
use rayon::prelude::*;

/// Where the camera is and how it looks: the ZYX Euler angles of the camera's
/// own frame (x along the image columns, y along the rows, z the optical axis),
/// which at zero is a vehicle's FRD body flying north with a nadir camera. A
/// camera on a vehicle composes the vehicle's attitude with its mount first
/// (`crate::source::synthetic::CameraPose::on_vehicle`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub position_m: [f64; 3],
    /// Rotation about the image columns: positive turns the view towards `+y`
    /// (a vehicle rolling right, heading north, looks west).
    pub roll_rad: f64,
    /// 0 = nadir, positive = tilted forward (towards `+x` at yaw 0).
    pub pitch_rad: f64,
    /// Heading of the image columns, clockwise from `+x` seen from above (from
    /// north towards east, i.e. `−y`), as an autopilot's yaw.
    pub yaw_rad: f64,
    pub intrinsics: Intrinsics,
}

impl Camera {
    /// `(optical axis, image column axis, image row axis)` in the world.
    #[inline]
    pub fn basis(&self) -> ([f64; 3], [f64; 3], [f64; 3]) {
        let (sp, cp) = self.pitch_rad.sin_cos();
        if self.roll_rad == 0.0 && self.yaw_rad == 0.0 {
            // The pitch-only camera (every survey view): the general case below
            // reduces to it, but [`Camera::ray`] (the reference renderer's and
            // the bench baseline's) would pay two more sines per ray.
            return ([sp, 0.0, -cp], [cp, 0.0, sp], [0.0, -1.0, 0.0]);
        }
        let (sr, cr) = self.roll_rad.sin_cos();
        let (sy, cy) = self.yaw_rad.sin_cos();
        // Camera → NED, Rz(yaw)·Ry(pitch)·Rx(roll), column by column.
        let x = [cy * cp, sy * cp, -sp];
        let y = [cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr];
        let z = [cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr];
        // NED → world (north, west, up).
        let world = |v: [f64; 3]| [v[0], -v[1], -v[2]];
        (world(z), world(x), world(y))
    }

    /// Ray direction through continuous pixel position (`col`, `row`), pixel
    /// centres at `+0.5`, scaled so its component along the optical axis is 1:
    /// the ray parameter at a hit is the depth.
    #[inline]
    pub fn ray(&self, col: f64, row: f64) -> [f64; 3] {
        let (cx, cy) = self.intrinsics.principal_px();
        let f = self.intrinsics.focal_px();
        let (a, u, v) = self.basis();
        direction(a, u, v, (col - cx) / f, (row - cy) / f)
    }
}

/// `a + x·u + y·v`, the one formula every camera ray goes through, so rays
/// built from precomputed parts have the same bits as [`Camera::ray`]'s.
#[inline]
fn direction(a: [f64; 3], u: [f64; 3], v: [f64; 3], x: f64, y: f64) -> [f64; 3] {
    [
        a[0] + x * u[0] + y * v[0],
        a[1] + x * u[1] + y * v[1],
        a[2] + x * u[2] + y * v[2],
    ]
}

/// A [`Camera`] unpacked once per frame (basis, principal point, focal
/// length), instead of once per ray.
pub(crate) struct Pinhole {
    pub o: [f64; 3],
    pub a: [f64; 3],
    pub u: [f64; 3],
    pub v: [f64; 3],
    pub cx: f64,
    pub cy: f64,
    pub f: f64,
    pub width: usize,
    pub height: usize,
}

impl Pinhole {
    fn new(camera: &Camera) -> Pinhole {
        let (a, u, v) = camera.basis();
        let (cx, cy) = camera.intrinsics.principal_px();
        Pinhole {
            o: camera.position_m,
            a,
            u,
            v,
            cx,
            cy,
            f: camera.intrinsics.focal_px(),
            width: camera.intrinsics.width(),
            height: camera.intrinsics.height(),
        }
    }

    /// `x` of [`Camera::ray`] for each of the `n` sample columns of each pixel
    /// (`n·width` values; the sample `sx` of pixel `i` at `i·n + sx`).
    fn sample_x(&self, n: usize) -> Vec<f64> {
        (0..self.width * n)
            .map(|k| (sample_pos(k / n, k % n, n) - self.cx) / self.f)
            .collect()
    }
}

/// Continuous image position of sample `s` of `n` along one axis of pixel `i`
/// (for odd `n` the middle sample is exactly the pixel centre `i + 0.5`).
#[inline]
fn sample_pos(i: usize, s: usize, n: usize) -> f64 {
    i as f64 + (s as f64 + 0.5) / n as f64
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RenderOptions {
    /// Colour samples per pixel along each axis (`n×n` per pixel, box filter).
    pub supersample: usize,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions { supersample: 3 }
    }
}

/// One rendered view: linear RGB in `[0, 1]` and depth in metres, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<[f32; 3]>,
    pub depth_m: Vec<f32>,
}

/// What a depth sensor does to the true depth before Z16 quantisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorModel {
    /// Metres per Z16 unit.
    pub scale_m: f64,
    /// Gaussian noise `σ = k·d²` (stereo depth error grows with the square of
    /// depth); `k` in 1/m.
    pub noise_per_m: f64,
    /// Fraction of pixels with no return.
    pub dropout: f64,
    /// Range beyond which the sensor gives no return, metres.
    pub max_range_m: f64,
    pub seed: u64,
}

impl Default for SensorModel {
    fn default() -> Self {
        SensorModel {
            scale_m: 0.001,
            noise_per_m: 0.0,
            dropout: 0.0,
            max_range_m: 65.0,
            seed: 0,
        }
    }
}

impl Frame {
    /// Rec. 601 luma of each pixel.
    pub fn luminance(&self) -> Vec<f32> {
        self.rgb.iter().map(|p| luma(*p)).collect()
    }

    /// The true depth as the core's depth image (metres, `+inf` sky).
    pub fn depth_image(&self) -> DepthImage {
        DepthImage::new(
            self.width,
            self.height,
            DepthData::Metres(self.depth_m.clone()),
        )
        .expect("frame size matches its data")
    }

    /// Depth as a RealSense gives it: Z16 with optional noise and dropout;
    /// sky, dropped pixels and anything beyond the range are 0 (no return).
    pub fn z16(&self, sensor: &SensorModel) -> DepthImage {
        let data = if sensor.noise_per_m > 0.0 || sensor.dropout > 0.0 {
            self.z16_data_noisy(sensor)
        } else {
            // No noise, no dropout: the range and the conversion in one pass.
            crate::synth::to_z16_within(&self.depth_m, sensor.scale_m, sensor.max_range_m)
        };
        DepthImage::new(
            self.width,
            self.height,
            DepthData::Z16 {
                data,
                scale_m: sensor.scale_m,
            },
        )
        .expect("frame size matches its data")
    }

    /// [`Frame::z16`]'s data through every stage of the sensor model.
    fn z16_data_noisy(&self, sensor: &SensorModel) -> Vec<u16> {
        let mut d = self.depth_m.clone();
        if sensor.noise_per_m > 0.0 {
            let mut s = sensor.seed ^ 0x5851_F42D_4C95_7F2D;
            for v in d.iter_mut() {
                let g = gaussian(&mut s);
                if v.is_finite() {
                    let z = *v as f64;
                    *v = (z + g * sensor.noise_per_m * z * z) as f32;
                }
            }
        }
        for v in d.iter_mut() {
            if (*v as f64) > sensor.max_range_m {
                *v = f32::INFINITY;
            }
        }
        if sensor.dropout > 0.0 {
            crate::synth::dropout(&mut d, sensor.dropout, sensor.seed);
        }
        crate::synth::to_z16(&d, sensor.scale_m)
    }

    /// 8-bit sRGB-less RGB bytes (for PNG output).
    pub fn rgb8(&self) -> Vec<u8> {
        self.rgb.iter().flat_map(|p| p.map(byte_of)).collect()
    }
}

/// `(c.clamp(0, 1) · 255).round()` as a byte (NaN: 0), without libm's `roundf`
/// (a call per channel on baseline x86-64): the truncation is a cast and the
/// fraction below 256 is exact, so the bytes are the same.
#[inline]
pub fn byte_of(c: f32) -> u8 {
    let v = c.clamp(0.0, 1.0) * 255.0;
    let t = v as u8;
    t + (v - t as f32 >= 0.5) as u8
}

#[inline]
pub fn luma(p: [f32; 3]) -> f32 {
    0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2]
}

fn gaussian(s: &mut u64) -> f64 {
    let mut u = || {
        *s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let (a, b) = (u(), u());
    (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
}

/// The first surface a ray meets.
#[derive(Debug, Clone, Copy)]
pub struct Hit<'a> {
    /// Ray parameter (the depth, for camera rays from [`Camera::ray`]).
    pub t: f64,
    pub normal: [f64; 3],
    pub texture: &'a Texture,
}

/// Entry parameter and the axis of the entered face of a ray into a box
/// (slab method); `None` if it misses or starts inside.
pub fn ray_box(min: [f64; 3], max: [f64; 3], o: [f64; 3], d: [f64; 3]) -> Option<(f64, usize)> {
    // Every axis's slab computed, then combined without a branch per axis: a
    // ray misses most boxes it is tested against, at an axis no predictor
    // guesses. The same bits as stopping at the first empty overlap (the
    // entry only grows and the exit only falls, so one empty stays empty).
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    let mut axis = 0;
    let mut outside = false;
    for k in 0..3 {
        let (a, b) = ((min[k] - o[k]) / d[k], (max[k] - o[k]) / d[k]);
        let (a, b) = if a < b { (a, b) } else { (b, a) };
        // Parallel to the slab: inside it or never in the box.
        let flat = d[k] == 0.0;
        outside |= flat & ((o[k] < min[k]) | (o[k] > max[k]));
        let (a, b) = if flat {
            (f64::NEG_INFINITY, f64::INFINITY)
        } else {
            (a, b)
        };
        axis = if a > t0 { k } else { axis };
        t0 = if a > t0 { a } else { t0 };
        t1 = t1.min(b);
    }
    if outside || t0 > t1 {
        return None;
    }
    (t0 > 0.0).then_some((t0, axis))
}

/// First parameter `t > 0` at which the ray meets the ellipsoid surface.
pub fn ray_ellipsoid(centre: [f64; 3], radii: [f64; 3], o: [f64; 3], d: [f64; 3]) -> Option<f64> {
    let oc = [
        (o[0] - centre[0]) / radii[0],
        (o[1] - centre[1]) / radii[1],
        (o[2] - centre[2]) / radii[2],
    ];
    let dd = [d[0] / radii[0], d[1] / radii[1], d[2] / radii[2]];
    let a = dot(dd, dd);
    let b = dot(oc, dd);
    let c = dot(oc, oc) - 1.0;
    let disc = b * b - a * c;
    if disc < 0.0 || a == 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let t_near = (-b - sq) / a;
    if t_near > 0.0 {
        return Some(t_near);
    }
    // Starting inside: the exit is not a surface seen from outside.
    None
}

#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Which surface a ray met (the hit's normal and texture are derived from it
/// only when shading needs them).
#[derive(Debug, Clone, Copy)]
enum Surface {
    Ground,
    /// Box index and the axis of the entered face.
    Box(usize, usize),
    Ellipsoid(usize),
}

/// The nearest surface over the ground and the primitives `prims` (box
/// indices below `scene.boxes.len()`, then ellipsoids after them), which must
/// come in ascending order: a later primitive replaces the best hit only when
/// strictly nearer, so ties go to the first in scene order.
#[inline]
fn nearest(
    scene: &Scene,
    prims: impl Iterator<Item = usize>,
    o: [f64; 3],
    d: [f64; 3],
) -> Option<(f64, Surface)> {
    let mut best: Option<(f64, Surface)> = None;
    if let Some(g) = &scene.ground {
        if d[2] < 0.0 && o[2] > g.z_m {
            best = Some(((g.z_m - o[2]) / d[2], Surface::Ground));
        }
    }
    let boxes = scene.boxes.len();
    for p in prims {
        if p < boxes {
            let b = &scene.boxes[p];
            if let Some((t, axis)) = ray_box(b.min_m, b.max_m, o, d) {
                if best.is_none_or(|h| t < h.0) {
                    best = Some((t, Surface::Box(p, axis)));
                }
            }
        } else {
            let e = &scene.ellipsoids[p - boxes];
            if let Some(t) = ray_ellipsoid(e.centre_m, e.radii_m, o, d) {
                if best.is_none_or(|h| t < h.0) {
                    best = Some((t, Surface::Ellipsoid(p - boxes)));
                }
            }
        }
    }
    best
}

/// Normal and texture of the surface found by [`nearest`] at parameter `t`.
#[inline]
fn hit_of(scene: &Scene, surface: Surface, t: f64, o: [f64; 3], d: [f64; 3]) -> Hit<'_> {
    match surface {
        Surface::Ground => Hit {
            t,
            normal: [0.0, 0.0, 1.0],
            texture: &scene
                .ground
                .as_ref()
                .expect("a ground hit has a ground")
                .texture,
        },
        Surface::Box(i, axis) => {
            let b = &scene.boxes[i];
            // Selected, not indexed: a store at a run-time index read back
            // as a whole stalls store-to-load forwarding (the hottest line of
            // a supersampled frame).
            let along = |k: usize| if axis == k { -d[k].signum() } else { 0.0 };
            let normal = [along(0), along(1), along(2)];
            let texture = if axis == 2 && normal[2] > 0.0 {
                &b.roof
            } else {
                &b.texture
            };
            Hit { t, normal, texture }
        }
        Surface::Ellipsoid(i) => {
            let e = &scene.ellipsoids[i];
            let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            let mut n = [0.0; 3];
            for k in 0..3 {
                n[k] = (p[k] - e.centre_m[k]) / (e.radii_m[k] * e.radii_m[k]);
            }
            let l = dot(n, n).sqrt();
            Hit {
                t,
                normal: [n[0] / l, n[1] / l, n[2] / l],
                texture: &e.texture,
            }
        }
    }
}

/// The nearest hit of the ray `o + t·d`, `t > 0`, testing every primitive:
/// the definition the binned renderer is held to.
pub fn trace<'a>(scene: &'a Scene, o: [f64; 3], d: [f64; 3]) -> Option<Hit<'a>> {
    let all = 0..scene.boxes.len() + scene.ellipsoids.len();
    nearest(scene, all, o, d).map(|(t, s)| hit_of(scene, s, t, o, d))
}

/// Fixed sun: walls, roofs and crowns shade differently, as in daylight.
const SUN: [f64; 3] = [0.37139068, 0.55708601, 0.74278135];

#[inline]
fn lit(albedo: [f32; 3], normal: [f64; 3]) -> [f32; 3] {
    times(albedo, light(normal))
}

#[inline]
fn light(normal: [f64; 3]) -> f32 {
    (0.45 + 0.55 * dot(normal, SUN).max(0.0)) as f32
}

#[inline]
fn times(albedo: [f32; 3], l: f32) -> [f32; 3] {
    [albedo[0] * l, albedo[1] * l, albedo[2] * l]
}

/// Pixels of a row traced before their textures are evaluated, so that the
/// texture sees its points [`Texture::BATCH`] at a time.
const CHUNK_PX: usize = 8;

/// Textured samples on one texture waiting for it: where they hit (one array
/// per axis, as [`Texture::albedo_batch`] takes them), the sun's light there
/// ([`light`]) and where their colours go.
#[derive(Default)]
struct Batch<'a> {
    texture: Option<&'a Texture>,
    len: usize,
    xyz: [[f64; Texture::BATCH]; 3],
    light: [f32; Texture::BATCH],
    slot: [u32; Texture::BATCH],
}

/// The colours of a run of samples, in the order they were traced. A textured
/// sample's colour is filled in when its batch is full, when a sample on
/// another texture comes, or at [`Shades::flush`]; each the same bits as
/// the sample's own [`Texture::albedo`] would give.
#[derive(Default)]
struct Shades<'a> {
    colours: Vec<[f32; 3]>,
    batch: Batch<'a>,
}

impl<'a> Shades<'a> {
    fn clear(&mut self) {
        self.colours.clear();
        self.batch.len = 0;
        self.batch.texture = None;
    }

    #[inline]
    fn push(&mut self, scene: &'a Scene, found: Option<(f64, Surface)>, o: [f64; 3], d: [f64; 3]) {
        match found {
            None => self.colours.push(scene.sky_rgb),
            Some((t, s)) => {
                let h = hit_of(scene, s, t, o, d);
                if h.texture.contrast == 0.0 {
                    self.colours.push(lit(h.texture.colour, h.normal));
                    return;
                }
                let same = self
                    .batch
                    .texture
                    .is_some_and(|b| std::ptr::eq(b, h.texture));
                if !same || self.batch.len == Texture::BATCH {
                    self.flush();
                    self.batch.texture = Some(h.texture);
                }
                let k = self.batch.len;
                let b = &mut self.batch;
                for c in 0..3 {
                    b.xyz[c][k] = o[c] + t * d[c];
                }
                b.light[k] = light(h.normal);
                b.slot[k] = self.colours.len() as u32;
                b.len += 1;
                self.colours.push([0.0; 3]);
            }
        }
    }

    /// Evaluates the waiting batch, filling in every colour still waiting (its
    /// spare lanes repeat its last point and are dropped).
    fn flush(&mut self) {
        let b = &mut self.batch;
        let (Some(texture), n @ 1..) = (b.texture, b.len) else {
            return;
        };
        for c in 0..3 {
            let last = b.xyz[c][n - 1];
            b.xyz[c][n..].fill(last);
        }
        let albedo = texture.albedo_batch(&b.xyz[0], &b.xyz[1], &b.xyz[2]);
        for ((a, l), slot) in albedo.iter().zip(b.light).zip(b.slot).take(n) {
            self.colours[slot as usize] = times(*a, l);
        }
        b.len = 0;
    }
}

/// Renders colour and depth of `scene` from `camera`: each ray is tested only
/// against the primitives binned to its tile, and for odd supersampling the
/// middle sample of each pixel is the depth ray, traced once for both.
pub fn render(scene: &Scene, camera: &Camera, opts: &RenderOptions) -> Frame {
    let cam = Pinhole::new(camera);
    let bins = Bins::new(scene, &cam);
    let (w, h) = (cam.width, cam.height);
    let n = opts.supersample.max(1);
    // The middle sample, if there is one, has the pixel centre's coordinates.
    let mid = (n % 2 == 1).then_some(n / 2);
    let xs = cam.sample_x(n);
    let xc = cam.sample_x(1);
    let o = cam.o;
    let mut rgb = vec![[0f32; 3]; w * h];
    let mut depth_m = vec![0f32; w * h];
    let inv = 1.0 / (n * n) as f32;
    rgb.par_chunks_mut(w)
        .zip(depth_m.par_chunks_mut(w))
        .enumerate()
        .for_each(|(r, (rgb_row, depth_row))| {
            let yc = (sample_pos(r, 0, 1) - cam.cy) / cam.f;
            let ys: Vec<f64> = (0..n)
                .map(|sy| (sample_pos(r, sy, n) - cam.cy) / cam.f)
                .collect();
            let mut shades = Shades::default();
            for i0 in (0..w).step_by(CHUNK_PX) {
                let pixels = i0..(i0 + CHUNK_PX).min(w);
                shades.clear();
                for i in pixels.clone() {
                    let list = bins.at(i, r);
                    let prims = || list.iter().map(|&p| p as usize);
                    let dc = direction(cam.a, cam.u, cam.v, xc[i], yc);
                    let centre = nearest(scene, prims(), o, dc);
                    depth_row[i] = centre.map_or(f32::INFINITY, |c| c.0 as f32);
                    for (sy, &y) in ys.iter().enumerate() {
                        for sx in 0..n {
                            let (d, found) = if mid == Some(sx) && mid == Some(sy) {
                                (dc, centre)
                            } else {
                                let d = direction(cam.a, cam.u, cam.v, xs[i * n + sx], y);
                                (d, nearest(scene, prims(), o, d))
                            };
                            shades.push(scene, found, o, d);
                        }
                    }
                }
                shades.flush();
                // Each pixel's samples summed in the order they were traced.
                for (i, samples) in pixels.zip(shades.colours.chunks_exact(n * n)) {
                    let mut acc = [0f32; 3];
                    for c in samples {
                        acc[0] += c[0];
                        acc[1] += c[1];
                        acc[2] += c[2];
                    }
                    rgb_row[i] = [acc[0] * inv, acc[1] * inv, acc[2] * inv];
                }
            }
        });
    Frame {
        width: w,
        height: h,
        rgb,
        depth_m,
    }
}

/// [`render`] by its definition: every ray through [`trace`] against every
/// primitive, textures from exact sines. Slow; the fast renderer's depth must
/// equal this one's bit for bit and its colour within the polynomial sines' error.
pub fn render_reference(scene: &Scene, camera: &Camera, opts: &RenderOptions) -> Frame {
    let w = camera.intrinsics.width();
    let h = camera.intrinsics.height();
    let n = opts.supersample.max(1);
    let o = camera.position_m;
    let mut rgb = vec![[0f32; 3]; w * h];
    let mut depth_m = vec![0f32; w * h];
    let inv = 1.0 / (n * n) as f32;
    rgb.par_chunks_mut(w)
        .zip(depth_m.par_chunks_mut(w))
        .enumerate()
        .for_each(|(r, (rgb_row, depth_row))| {
            for i in 0..w {
                let d = camera.ray(i as f64 + 0.5, r as f64 + 0.5);
                depth_row[i] = trace(scene, o, d).map_or(f32::INFINITY, |h| h.t as f32);
                let mut acc = [0f32; 3];
                for sy in 0..n {
                    for sx in 0..n {
                        let d = camera.ray(sample_pos(i, sx, n), sample_pos(r, sy, n));
                        let c = match trace(scene, o, d) {
                            None => scene.sky_rgb,
                            Some(h) => {
                                let p = [o[0] + h.t * d[0], o[1] + h.t * d[1], o[2] + h.t * d[2]];
                                lit(h.texture.albedo_exact(p), h.normal)
                            }
                        };
                        acc[0] += c[0];
                        acc[1] += c[1];
                        acc[2] += c[2];
                    }
                }
                rgb_row[i] = [acc[0] * inv, acc[1] * inv, acc[2] * inv];
            }
        });
    Frame {
        width: w,
        height: h,
        rgb,
        depth_m,
    }
}

/// Depth only (metres along the optical axis at each pixel centre, `+inf` for
/// sky): what a depth camera sees, without the cost of shading.
pub fn render_depth(scene: &Scene, camera: &Camera) -> Vec<f32> {
    let cam = Pinhole::new(camera);
    let bins = Bins::new(scene, &cam);
    let w = cam.width;
    let xc = cam.sample_x(1);
    let mut depth_m = vec![0f32; w * cam.height];
    depth_m.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
        let y = (sample_pos(r, 0, 1) - cam.cy) / cam.f;
        for (i, out) in row.iter_mut().enumerate() {
            let d = direction(cam.a, cam.u, cam.v, xc[i], y);
            let prims = bins.at(i, r).iter().map(|&p| p as usize);
            *out = nearest(scene, prims, cam.o, d).map_or(f32::INFINITY, |c| c.0 as f32);
        }
    });
    depth_m
}

/// The camera of dense view `x_m` on a scene's survey line at `width`×`height`.
pub fn survey_camera(scene: &Scene, x_m: f64, width: usize, height: usize) -> Camera {
    let s = &scene.survey;
    Camera {
        position_m: [x_m, s.y_m, s.altitude_m],
        roll_rad: 0.0,
        pitch_rad: s.pitch_rad,
        yaw_rad: 0.0,
        intrinsics: Intrinsics::from_hfov_deg(width, height, s.hfov_deg, None)
            .expect("scene validation keeps the field of view in range"),
    }
}

/// Writes 8-bit RGB as a PNG file.
pub fn write_png(
    path: &std::path::Path,
    width: usize,
    height: usize,
    rgb8: &[u8],
) -> std::io::Result<()> {
    let file = std::fs::File::create(path)?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().map_err(std::io::Error::other)?;
    w.write_image_data(rgb8).map_err(std::io::Error::other)?;
    w.finish().map_err(std::io::Error::other)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_z16_in_one_pass_equals_the_sensor_stages() {
        // Ties of the Z16 rounding, their neighbours, both ends of its range,
        // the sensor's range and beyond, sky, NaN, negative and zero depths.
        let mut d = vec![
            f32::NAN,
            f32::INFINITY,
            -f32::INFINITY,
            -1.0,
            0.0,
            0.004,
            0.005,
        ];
        for k in 0..70_000u32 {
            let tie = (k as f64 + 0.5) * 0.001;
            let f = tie as f32;
            d.extend([
                f,
                f32::from_bits(f.to_bits() - 1),
                f32::from_bits(f.to_bits() + 1),
            ]);
        }
        d.extend((0..100_000u32).map(|i| f32::from_bits(i.wrapping_mul(0x9E37_79B9) >> 1)));
        d.extend([
            65.0,
            f32::from_bits(65.0f32.to_bits() - 1),
            f32::from_bits(65.0f32.to_bits() + 1),
            65.5,
            65.535,
            65.5345,
        ]);
        let frame = Frame {
            width: d.len(),
            height: 1,
            rgb: Vec::new(),
            depth_m: d,
        };
        for (scale_m, max_range_m) in [(0.001, 65.0), (0.01, 300.0), (0.001, 1e9), (1.0, 0.0)] {
            let sensor = SensorModel {
                scale_m,
                max_range_m,
                ..SensorModel::default()
            };
            assert_eq!(
                crate::synth::to_z16_within(&frame.depth_m, scale_m, max_range_m),
                frame.z16_data_noisy(&sensor),
                "scale {scale_m} range {max_range_m}"
            );
        }
    }

    #[test]
    fn bytes_without_roundf_are_the_bytes_of_roundf() {
        let by_round = |c: f32| (c.clamp(0.0, 1.0) * 255.0).round() as u8;
        let mut cs = vec![f32::NAN, f32::INFINITY, -f32::INFINITY, -0.5, 2.0];
        for k in 0..=255u32 {
            // The colour whose scaled value is a tie, and its neighbours.
            let tie = (k as f32 + 0.5) / 255.0;
            cs.extend([
                tie,
                f32::from_bits(tie.to_bits() - 1),
                f32::from_bits(tie.to_bits() + 1),
                k as f32 / 255.0,
            ]);
        }
        // Every representable value in [0, 1] by a stride.
        cs.extend((0..=1.0f32.to_bits()).step_by(97).map(f32::from_bits));
        for c in cs {
            assert_eq!(byte_of(c), by_round(c), "{c}");
        }
    }

    #[test]
    fn colour_is_each_sample_traced_and_textured_one_at_a_time_bit_for_bit() {
        // The renderer's colour by its definition with the polynomial sines:
        // every sample ray through `trace` (every primitive, no bins), its
        // texture evaluated alone, the samples summed in row-major order. The
        // bins, the shared middle ray and the batched textures must not move a
        // bit (a short run of one texture, an edge between two, sky).
        let manifest = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        for name in ["district", "tree", "roof"] {
            let sc = Scene::load(&manifest.join(format!("scenes/{name}.toml"))).unwrap();
            let s = &sc.survey;
            for x in [s.start_x_m, 0.5 * (s.start_x_m + s.end_x_m)] {
                let cam = survey_camera(&sc, x, 90, 60);
                for n in [1, 2, 3] {
                    let frame = render(&sc, &cam, &RenderOptions { supersample: n });
                    let o = cam.position_m;
                    let inv = 1.0 / (n * n) as f32;
                    for r in 0..60 {
                        for i in 0..90 {
                            let mut acc = [0f32; 3];
                            for sy in 0..n {
                                for sx in 0..n {
                                    let d = cam.ray(sample_pos(i, sx, n), sample_pos(r, sy, n));
                                    let c = match trace(&sc, o, d) {
                                        None => sc.sky_rgb,
                                        Some(h) => {
                                            let t = h.t;
                                            let p =
                                                [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                                            lit(h.texture.albedo(p), h.normal)
                                        }
                                    };
                                    for k in 0..3 {
                                        acc[k] += c[k];
                                    }
                                }
                            }
                            let want = acc.map(|a| (a * inv).to_bits());
                            let got = frame.rgb[r * 90 + i].map(f32::to_bits);
                            assert_eq!(got, want, "{name} x={x} ss={n} pixel ({i}, {r})");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_middle_sample_of_an_odd_grid_is_the_pixel_centre_bit_for_bit() {
        for n in [1usize, 3, 5, 7, 9, 11] {
            for i in [0usize, 1, 319, 640, 8191] {
                assert_eq!(
                    sample_pos(i, n / 2, n).to_bits(),
                    (i as f64 + 0.5).to_bits(),
                    "n {n} i {i}"
                );
            }
        }
    }
}
