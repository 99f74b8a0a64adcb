//! The two reconstruction renderers of DESIGN §3 on luminance images of views
//! that share orientation and intrinsics and differ by a move along `+x`:
//! (a) light-field rendering through the plane at `w_opt`, blending the two
//! neighbouring captures by distance; (b) depth-aided warping, both neighbours
//! forward-warped by their own depth, disocclusion holes filled from the other.

/// Where sky is put when a renderer needs a finite depth, metres.
pub(crate) const SKY_M: f64 = 1e5;

/// A dense view: luminance in `[0, 1]` and depth along the optical axis.
#[derive(Debug, Clone)]
pub struct View {
    pub x_m: f64,
    pub lum: Vec<f32>,
    pub depth_m: Vec<f32>,
}

/// Camera geometry shared by all views of a survey line.
#[derive(Debug, Clone, Copy)]
pub struct Geometry {
    pub width: usize,
    pub height: usize,
    pub focal_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    pub pitch_rad: f64,
}

impl Geometry {
    /// The geometry of `scene`'s survey camera at `width × height`: its intrinsics
    /// (the same at every position along the line) and pitch.
    pub fn of_survey(scene: &crate::scene::Scene, width: usize, height: usize) -> Geometry {
        let s = &scene.survey;
        let cam = crate::render::survey_camera(scene, s.start_x_m, width, height);
        let (cx_px, cy_px) = cam.intrinsics.principal_px();
        Geometry {
            width,
            height,
            focal_px: cam.intrinsics.focal_px(),
            cx_px,
            cy_px,
            pitch_rad: s.pitch_rad,
        }
    }

    #[inline]
    pub(crate) fn norm(&self, i: usize, r: usize) -> (f64, f64) {
        (
            (i as f64 + 0.5 - self.cx_px) / self.focal_px,
            (r as f64 + 0.5 - self.cy_px) / self.focal_px,
        )
    }

    /// Continuous pixel index (centres at integers) and depth, in a camera
    /// displaced by `-delta_m` along x, of the point at depth `t` on the ray
    /// through normalised `(x, y)` of a camera at 0.
    /// `sc` is the pitch's `(sin, cos)`, computed once by the caller (the
    /// per-pixel loops spent 5 % of the evaluation in `sin_cos`).
    #[inline]
    pub(crate) fn reproject(
        &self,
        (s, c): (f64, f64),
        x: f64,
        y: f64,
        t: f64,
        delta_m: f64,
    ) -> Option<(f64, f64, f64)> {
        let depth = t + delta_m * s;
        if depth <= 1e-6 {
            return None;
        }
        let xs = (t * x + delta_m * c) / depth;
        let ys = t * y / depth;
        Some((
            xs * self.focal_px + self.cx_px - 0.5,
            ys * self.focal_px + self.cy_px - 0.5,
            depth,
        ))
    }

    #[inline]
    pub(crate) fn inside(&self, col: f64, row: f64) -> bool {
        col >= -0.5
            && row >= -0.5
            && col <= self.width as f64 - 0.5
            && row <= self.height as f64 - 0.5
    }

    /// Catmull-Rom bicubic sample at a continuous pixel index (clamped at the
    /// border): sharper than sample, so resampling blur does not swamp the
    /// aliasing and occlusion errors the spacing is about.
    #[inline]
    fn sample(&self, img: &[f32], col: f64, row: f64) -> f32 {
        let w = self.width as i64;
        let h = self.height as i64;
        let col = col.clamp(0.0, (w - 1) as f64);
        let row = row.clamp(0.0, (h - 1) as f64);
        // Clamped to non-negative: truncation is the floor (a cast, where
        // `floor` is a libm call on baseline x86-64).
        let c0 = col as i64;
        let r0 = row as i64;
        let wc = catmull_rom((col - c0 as f64) as f32);
        let wr = catmull_rom((row - r0 as f64) as f32);
        let mut acc = 0f32;
        // Every tap inside: no clamping, four contiguous values a row (the
        // same sums in the same order as the clamped taps below).
        if c0 >= 1 && r0 >= 1 && c0 + 2 < w && r0 + 2 < h {
            let (c0, r0) = (c0 as usize, r0 as usize);
            for (dr, wy) in wr.iter().enumerate() {
                let start = (r0 + dr - 1) * self.width + c0 - 1;
                let taps: &[f32; 4] = img[start..start + 4].try_into().expect("four taps");
                let mut s = 0f32;
                for (wx, v) in wc.iter().zip(taps) {
                    s += wx * v;
                }
                acc += wy * s;
            }
            return acc;
        }
        for (dr, wy) in wr.iter().enumerate() {
            let rr = (r0 + dr as i64 - 1).clamp(0, h - 1) as usize;
            let line = &img[rr * self.width..(rr + 1) * self.width];
            let mut s = 0f32;
            for (dc, wx) in wc.iter().enumerate() {
                let cc = (c0 + dc as i64 - 1).clamp(0, w - 1) as usize;
                s += wx * line[cc];
            }
            acc += wy * s;
        }
        acc
    }
}

/// `x.round()` (half away from zero) without the libm call baseline x86-64
/// makes of it (no SSE4.1 `roundsd`): below 2^52 the truncation and the
/// fraction `x − trunc(x)` are exact, so this is the same value (up to the
/// sign of a zero); beyond, and for NaN and infinities, `round` itself.
#[inline]
pub(crate) fn round_half_away(x: f64) -> f64 {
    if x.abs() < 4.5e15 {
        let t = x as i64 as f64;
        let f = x - t;
        if f >= 0.5 {
            t + 1.0
        } else if f <= -0.5 {
            t - 1.0
        } else {
            t
        }
    } else {
        x.round()
    }
}

/// Catmull-Rom weights of the taps at -1, 0, 1, 2 for fractional offset `t`.
#[inline]
fn catmull_rom(t: f32) -> [f32; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// Weight of capture `a` for a view at `x_t` between `a` and `b`.
fn weight_a(a: &View, b: &View, x_t: f64) -> f32 {
    let span = b.x_m - a.x_m;
    if span.abs() < 1e-12 {
        0.5
    } else {
        ((b.x_m - x_t) / span).clamp(0.0, 1.0) as f32
    }
}

/// (a) Light-field rendering through the plane at inverse depth `w_opt_per_m`.
pub fn lightfield(g: &Geometry, a: &View, b: &View, x_t: f64, w_opt_per_m: f64) -> Vec<f32> {
    let mut out = vec![0f32; g.width * g.height];
    let sc = g.pitch_rad.sin_cos();
    for r in 0..g.height {
        for i in 0..g.width {
            out[r * g.width + i] = lightfield_px(g, sc, a, b, x_t, w_opt_per_m, i, r);
        }
    }
    out
}

/// One pixel of [`lightfield`].
#[allow(clippy::too_many_arguments)]
fn lightfield_px(
    g: &Geometry,
    sc: (f64, f64),
    a: &View,
    b: &View,
    x_t: f64,
    w_opt_per_m: f64,
    i: usize,
    r: usize,
) -> f32 {
    let t = if w_opt_per_m > 1.0 / SKY_M {
        1.0 / w_opt_per_m
    } else {
        SKY_M
    };
    let wa = weight_a(a, b, x_t);
    let (x, y) = g.norm(i, r);
    let sample = |v: &View| {
        g.reproject(sc, x, y, t, x_t - v.x_m)
            .filter(|p| g.inside(p.0, p.1))
            .map(|p| g.sample(&v.lum, p.0, p.1))
    };
    match (sample(a), sample(b)) {
        (Some(va), Some(vb)) => wa * va + (1.0 - wa) * vb,
        (Some(va), None) => va,
        (None, Some(vb)) => vb,
        (None, None) => {
            // Off both frames: the nearer capture, clamped at its border.
            let v = if wa >= 0.5 { a } else { b };
            match g.reproject(sc, x, y, t, x_t - v.x_m) {
                Some(p) => g.sample(&v.lum, p.0, p.1),
                None => v.lum[r * g.width + i],
            }
        }
    }
}

/// One source warped into the target: luminance and whether it is valid.
fn warp_one(g: &Geometry, src: &View, x_t: f64) -> (Vec<f32>, Vec<bool>) {
    let (w, h) = (g.width, g.height);
    let n = w * h;
    // Forward: splat the source's depth into the target's z-buffer.
    let mut z = vec![f64::INFINITY; n];
    let to_target = src.x_m - x_t;
    let sc = g.pitch_rad.sin_cos();
    for r in 0..h {
        for i in 0..w {
            let d = src.depth_m[r * w + i] as f64;
            let t = if d.is_finite() && d > 0.0 { d } else { SKY_M };
            let (x, y) = g.norm(i, r);
            if let Some((col, row, depth)) = g.reproject(sc, x, y, t, to_target) {
                let (c, rr) = (round_half_away(col), round_half_away(row));
                if c >= 0.0 && rr >= 0.0 && (c as usize) < w && (rr as usize) < h {
                    let k = rr as usize * w + c as usize;
                    if depth < z[k] {
                        z[k] = depth;
                    }
                }
            }
        }
    }
    // Cracks left by nearest-pixel splatting: the farthest neighbour's depth.
    // A disocclusion hole filled so fails the consistency test below, as it should.
    let mut zf = z.clone();
    for r in 0..h {
        for i in 0..w {
            if z[r * w + i].is_finite() {
                continue;
            }
            let mut far = f64::NEG_INFINITY;
            for dr in -1i64..=1 {
                for dc in -1i64..=1 {
                    let (rr, cc) = (r as i64 + dr, i as i64 + dc);
                    if rr >= 0 && cc >= 0 && (rr as usize) < h && (cc as usize) < w {
                        let v = z[rr as usize * w + cc as usize];
                        if v.is_finite() {
                            far = far.max(v);
                        }
                    }
                }
            }
            if far.is_finite() {
                zf[r * w + i] = far;
            }
        }
    }
    // Backward: fetch colour at the warped depth, kept only where the source
    // itself sees that point (its own depth agrees).
    let mut lum = vec![0f32; n];
    let mut valid = vec![false; n];
    let from_target = x_t - src.x_m;
    for r in 0..h {
        for i in 0..w {
            let t = zf[r * w + i];
            if !t.is_finite() {
                continue;
            }
            let (x, y) = g.norm(i, r);
            let Some((col, row, depth)) = g.reproject(sc, x, y, t, from_target) else {
                continue;
            };
            if !g.inside(col, row) {
                continue;
            }
            let (c, rr) = (
                (round_half_away(col) as usize).min(w - 1),
                (round_half_away(row) as usize).min(h - 1),
            );
            let ds = src.depth_m[rr * w + c] as f64;
            let ds = if ds.is_finite() && ds > 0.0 {
                ds
            } else {
                SKY_M
            };
            let agree = if depth > 0.5 * SKY_M {
                ds > 0.5 * SKY_M
            } else {
                (ds - depth).abs() <= 0.02 * depth + 0.05
            };
            if agree {
                lum[r * w + i] = g.sample(&src.lum, col, row);
                valid[r * w + i] = true;
            }
        }
    }
    (lum, valid)
}

/// (b) Depth-aided warping; pixels neither neighbour sees fall back to (a).
pub fn warp(g: &Geometry, a: &View, b: &View, x_t: f64, w_opt_per_m: f64) -> Vec<f32> {
    let (la, va) = warp_one(g, a, x_t);
    let (lb, vb) = warp_one(g, b, x_t);
    let wa = weight_a(a, b, x_t);
    let sc = g.pitch_rad.sin_cos();
    let mut out = vec![0f32; g.width * g.height];
    for (k, o) in out.iter_mut().enumerate() {
        *o = match (va[k], vb[k]) {
            (true, true) => wa * la[k] + (1.0 - wa) * lb[k],
            (true, false) => la[k],
            (false, true) => lb[k],
            (false, false) => {
                lightfield_px(g, sc, a, b, x_t, w_opt_per_m, k % g.width, k / g.width)
            }
        };
    }
    out
}
