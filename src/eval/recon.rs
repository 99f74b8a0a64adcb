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

/// A reprojected point is in front of the camera when its depth is over this (metres);
/// [`Geometry::reproject`] and the passes that fold its test into a row's lanes share it.
pub(crate) const IN_FRONT_M: f64 = 1e-6;

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

    /// [`Self::norm`]'s `x` of every column and `y` of every row, the same
    /// bits: computed once per image, where a per-pixel loop paid a division
    /// for each pixel.
    pub(crate) fn norm_tables(&self) -> (Vec<f64>, Vec<f64>) {
        (
            (0..self.width).map(|i| self.norm(i, 0).0).collect(),
            (0..self.height).map(|r| self.norm(0, r).1).collect(),
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
        let (col, row, depth) = self.reproject_unchecked((s, c), x, y, t, delta_m);
        if depth <= IN_FRONT_M {
            return None;
        }
        Some((col, row, depth))
    }

    /// [`Self::reproject`] without its test of the depth: a column, row and depth whatever
    /// the depth (meaningless unless it is over [`IN_FRONT_M`]), computed the same way.
    #[inline(always)]
    pub(crate) fn reproject_unchecked(
        &self,
        (s, c): (f64, f64),
        x: f64,
        y: f64,
        t: f64,
        delta_m: f64,
    ) -> (f64, f64, f64) {
        let depth = t + delta_m * s;
        let xs = (t * x + delta_m * c) / depth;
        let ys = t * y / depth;
        (
            xs * self.focal_px + self.cx_px - 0.5,
            ys * self.focal_px + self.cy_px - 0.5,
            depth,
        )
    }

    #[inline]
    pub(crate) fn inside(&self, col: f64, row: f64) -> bool {
        self.inside_col(col) && self.inside_row(row)
    }

    /// Whether a continuous column (row) index lies within the image's (NaN does not).
    #[inline]
    fn inside_col(&self, col: f64) -> bool {
        col >= -0.5 && col <= self.width as f64 - 0.5
    }

    #[inline]
    fn inside_row(&self, row: f64) -> bool {
        row >= -0.5 && row <= self.height as f64 - 0.5
    }

    /// Catmull-Rom bicubic sample at a continuous pixel index (clamped at the
    /// border): sharper than sample, so resampling blur does not swamp the
    /// aliasing and occlusion errors the spacing is about.
    #[cfg(test)]
    fn sample(&self, img: &[f32], col: f64, row: f64) -> f32 {
        self.sample_taps(img, Tap::at(col, self.width), Tap::at(row, self.height))
    }

    /// [`Self::sample`] with each axis's taps already found. Always inlined, so that the
    /// warp's AVX2 build compiles it for AVX2 too.
    #[inline(always)]
    fn sample_taps(&self, img: &[f32], col: Tap, row: Tap) -> f32 {
        let w = self.width as i64;
        let h = self.height as i64;
        let (c0, wc) = (col.first, col.weights);
        let (r0, wr) = (row.first, row.weights);
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
        let cols = col.indices(self.width);
        for (rr, wy) in row.indices(self.height).into_iter().zip(wr) {
            let line = &img[rr * self.width..(rr + 1) * self.width];
            acc += wy * tap_sum(line, cols, &wc);
        }
        acc
    }
}

/// One axis of a Catmull-Rom sample: the pixel at or before the position (clamped to the
/// image) and the weights of the taps from one before it to two after.
#[derive(Debug, Clone, Copy)]
struct Tap {
    first: i64,
    weights: [f32; 4],
}

impl Tap {
    /// The four taps' pixels on an axis of `n`, clamped to it.
    #[inline]
    fn indices(self, n: usize) -> [usize; 4] {
        let last = n as i64 - 1;
        [0, 1, 2, 3].map(|d| (self.first + d - 1).clamp(0, last) as usize)
    }

    /// Positions [`Tap::at_lanes`] takes at once.
    const LANES: usize = 8;

    /// [`Tap::at`] at [`Tap::LANES`] positions, each with the same bits: the positions are
    /// the vector's lanes (the pixel by an `i32` truncation, which packs where `i64`'s does
    /// not, and is the same integer on a clamped axis shorter than 2^31 pixels). Always
    /// inlined, as [`Geometry::sample_taps`].
    #[inline(always)]
    fn at_lanes(x: [f64; Tap::LANES], n: usize) -> TapLanes {
        let hi = (n as i64 - 1) as f64;
        let x = x.map(|x| x.clamp(0.0, hi));
        let first = x.map(|x| x as i32);
        let mut t = [0f32; Tap::LANES];
        for l in 0..Tap::LANES {
            t[l] = (x[l] - first[l] as f64) as f32;
        }
        // `catmull_rom`, a weight at a time across the lanes.
        let (mut t2, mut t3) = ([0f32; Tap::LANES], [0f32; Tap::LANES]);
        for l in 0..Tap::LANES {
            t2[l] = t[l] * t[l];
            t3[l] = t2[l] * t[l];
        }
        let mut w = [[0f32; Tap::LANES]; 4];
        for l in 0..Tap::LANES {
            let (t, t2, t3) = (t[l], t2[l], t3[l]);
            w[0][l] = 0.5 * (-t3 + 2.0 * t2 - t);
            w[1][l] = 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0);
            w[2][l] = 0.5 * (-3.0 * t3 + 4.0 * t2 + t);
            w[3][l] = 0.5 * (t3 - t2);
        }
        TapLanes { first, weights: w }
    }

    /// The taps at continuous index `x` on an axis of `n` pixels.
    #[inline]
    fn at(x: f64, n: usize) -> Tap {
        let x = x.clamp(0.0, (n as i64 - 1) as f64);
        // Clamped to non-negative: truncation is the floor (a cast, where
        // `floor` is a libm call on baseline x86-64).
        let first = x as i64;
        Tap {
            first,
            weights: catmull_rom((x - first as f64) as f32),
        }
    }
}

/// [`Tap`]s at [`Tap::LANES`] positions, a field at a time across the positions (the lanes).
#[derive(Debug, Clone, Copy)]
struct TapLanes {
    first: [i32; Tap::LANES],
    weights: [[f32; Tap::LANES]; 4],
}

impl TapLanes {
    /// Lane `l`'s taps.
    #[inline(always)]
    fn tap(&self, l: usize) -> Tap {
        Tap {
            first: self.first[l] as i64,
            weights: [0, 1, 2, 3].map(|d| self.weights[d][l]),
        }
    }
}

/// The taps' weighted sum along one image line: `Σ weights[k] · line[idx[k]]`, from zero, in
/// tap order.
#[inline]
fn tap_sum(line: &[f32], idx: [usize; 4], weights: &[f32; 4]) -> f32 {
    let mut s = 0f32;
    for (c, wx) in idx.into_iter().zip(weights) {
        s += wx * line[c];
    }
    s
}

/// The pixel nearest continuous index `x` (centres at integers) for `x` in `[-0.5, 2^31 - 1)`:
/// `x.round()` (half away from zero) saturated at 0. In that range the truncation and the
/// fraction `x − trunc(x)` are exact, so the half is decided exactly. By an integer compare,
/// where `round` is a libm call on baseline x86-64 (rounding to a float and converting that
/// back made the warp's forward pass a fifth slower); in `i32`, whose conversion packs where
/// `usize`'s does not. Outside the range: garbage, but no panic.
#[inline(always)]
fn nearest_i32(x: f64) -> i32 {
    let t = x as i32;
    t.wrapping_add(i32::from(x - t as f64 >= 0.5))
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
    Plane::new(g, a, b, x_t, w_opt_per_m).render(g)
}

/// [`lightfield`]'s plane seen from its two captures. The plane lies at one depth and the
/// views differ by a move along `x`, so where a target pixel lands in a capture is separable:
/// its column depends on the pixel's column only, its row on its row
/// ([`Geometry::reproject`] of the same values, the same bits). Each column and row is
/// projected once, where each pixel cost two projections and their taps.
struct Plane<'a> {
    a: PlaneSide<'a>,
    b: PlaneSide<'a>,
    /// Capture `a`'s weight ([`weight_a`]).
    wa: f32,
}

/// The plane in one capture: per target column (row) whether it lands within the capture's
/// columns (rows) and the taps there; `None` when the plane is behind the capture.
struct PlaneSide<'a> {
    view: &'a View,
    axes: Option<(Vec<AxisTap>, Vec<AxisTap>)>,
}

/// Whether a target column (row) lands within the capture's, and its taps there.
type AxisTap = (bool, Tap);

impl<'a> Plane<'a> {
    fn new(g: &Geometry, a: &'a View, b: &'a View, x_t: f64, w_opt_per_m: f64) -> Plane<'a> {
        let t = if w_opt_per_m > 1.0 / SKY_M {
            1.0 / w_opt_per_m
        } else {
            SKY_M
        };
        let sc = g.pitch_rad.sin_cos();
        let (xs, ys) = g.norm_tables();
        let side = |view: &'a View| {
            let delta = x_t - view.x_m;
            // Where the plane is behind the capture `reproject` gives `None` for every pixel.
            let axes = g.reproject(sc, 0.0, 0.0, t, delta).map(|_| {
                let cols = xs
                    .iter()
                    .map(|&x| {
                        let col = g.reproject(sc, x, 0.0, t, delta).map_or(f64::NAN, |p| p.0);
                        (g.inside_col(col), Tap::at(col, g.width))
                    })
                    .collect();
                let rows = ys
                    .iter()
                    .map(|&y| {
                        let row = g.reproject(sc, 0.0, y, t, delta).map_or(f64::NAN, |p| p.1);
                        (g.inside_row(row), Tap::at(row, g.height))
                    })
                    .collect();
                (cols, rows)
            });
            PlaneSide { view, axes }
        };
        Plane {
            a: side(a),
            b: side(b),
            wa: weight_a(a, b, x_t),
        }
    }

    /// The rendering, row by row. A pixel is each capture's bicubic sample where the plane
    /// lands within it, blended by distance; off both, the nearer capture's sample clamped at
    /// its border (its own pixel where the plane is behind it).
    fn render(&self, g: &Geometry) -> Vec<f32> {
        let w = g.width;
        let mut out = vec![0f32; w * g.height];
        let (mut a, mut b) = (SideRows::new(g, &self.a), SideRows::new(g, &self.b));
        let wa = self.wa;
        let nearer_is_a = wa >= 0.5;
        let a_cols = self.a.axes.as_ref().map(|(cols, _)| cols.as_slice());
        let b_cols = self.b.axes.as_ref().map(|(cols, _)| cols.as_slice());
        for (r, line) in out.chunks_exact_mut(w).enumerate() {
            let (va, a_row) = a.row(g, r);
            let (vb, b_row) = b.row(g, r);
            let nearer = if nearer_is_a {
                (va, &self.a)
            } else {
                (vb, &self.b)
            };
            for (i, o) in line.iter_mut().enumerate() {
                let in_a = a_row && a_cols.is_some_and(|c| c[i].0);
                let in_b = b_row && b_cols.is_some_and(|c| c[i].0);
                *o = match (in_a, in_b) {
                    (true, true) => wa * va[i] + (1.0 - wa) * vb[i],
                    (true, false) => va[i],
                    (false, true) => vb[i],
                    (false, false) => match nearer.1.axes {
                        Some(_) => nearer.0[i],
                        None => nearer.1.view.lum[r * w + i],
                    },
                };
            }
        }
        out
    }
}

/// One capture's bicubic samples of the plane, a target row at a time. Every target row
/// samples the same four capture rows, each at the target columns' taps: the taps' sum along
/// each capture row ([`Geometry::sample_taps`]'s inner sums, the same operations in the same
/// order) is made once per capture row and kept, so a target row is four products per pixel
/// where per-pixel sampling made twenty, and neighbouring target rows share their capture
/// rows.
struct SideRows<'a> {
    lum: &'a [f32],
    /// Per target column: the four capture columns (clamped to the image) and their weights.
    cols: Vec<([usize; 4], [f32; 4])>,
    rows: &'a [AxisTap],
    /// The sums along capture row `k`, at `k * width`, once `summed[k]`.
    sums: Vec<f32>,
    summed: Vec<bool>,
    /// The current target row's samples.
    out: Vec<f32>,
}

impl<'a> SideRows<'a> {
    fn new(g: &Geometry, side: &'a PlaneSide) -> SideRows<'a> {
        let Some((cols, rows)) = side.axes.as_ref() else {
            return SideRows {
                lum: &[],
                cols: Vec::new(),
                rows: &[],
                sums: Vec::new(),
                summed: Vec::new(),
                out: Vec::new(),
            };
        };
        SideRows {
            lum: &side.view.lum,
            cols: cols
                .iter()
                .map(|(_, t)| (t.indices(g.width), t.weights))
                .collect(),
            rows,
            sums: vec![0f32; g.width * g.height],
            summed: vec![false; g.height],
            out: vec![0f32; g.width],
        }
    }

    /// Target row `r`'s samples (at every column, in range or not) and whether the row lands
    /// within the capture's rows; nothing for a capture the plane is behind.
    fn row(&mut self, g: &Geometry, r: usize) -> (&[f32], bool) {
        let Some(&(r_in, rt)) = self.rows.get(r) else {
            return (&[], false);
        };
        let w = g.width;
        let src = rt.indices(g.height);
        for &k in &src {
            if !self.summed[k] {
                let line = &self.lum[k * w..(k + 1) * w];
                for ((idx, wx), s) in self.cols.iter().zip(&mut self.sums[k * w..(k + 1) * w]) {
                    *s = tap_sum(line, *idx, wx);
                }
                self.summed[k] = true;
            }
        }
        let [s0, s1, s2, s3] = src.map(|k| &self.sums[k * w..(k + 1) * w]);
        let [w0, w1, w2, w3] = rt.weights;
        for (i, o) in self.out.iter_mut().enumerate() {
            let mut acc = 0f32;
            acc += w0 * s0[i];
            acc += w1 * s1[i];
            acc += w2 * s2[i];
            acc += w3 * s3[i];
            *o = acc;
        }
        (&self.out, r_in)
    }
}

/// One source warped into the target: luminance and whether it is valid. Compiled for AVX2
/// too, taken where the CPU has it: the same IEEE operations in the same order four lanes
/// wide (Rust fuses no multiply-add), so the same bits.
fn warp_one(g: &Geometry, src: &View, x_t: f64) -> (Vec<f32>, Vec<bool>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above, cached by std).
        return unsafe { warp_one_avx2(g, src, x_t) };
    }
    warp_one_with::<false>(g, src, x_t)
}

/// [`warp_one_with`] compiled for AVX2, its samples gathered eight at a time.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn warp_one_avx2(g: &Geometry, src: &View, x_t: f64) -> (Vec<f32>, Vec<bool>) {
    warp_one_with::<true>(g, src, x_t)
}

/// The warp; `AVX2` only where the CPU has AVX2 (the samples by [`sample_lanes_avx2`]).
#[inline(always)]
fn warp_one_with<const AVX2: bool>(g: &Geometry, src: &View, x_t: f64) -> (Vec<f32>, Vec<bool>) {
    let (w, h) = (g.width, g.height);
    let n = w * h;
    // Forward: splat the source's depth into the target's z-buffer.
    let (mut z, mut zf) = WARP_DEPTHS.take();
    z.clear();
    z.resize(n, f64::INFINITY);
    let to_target = src.x_m - x_t;
    let sc = g.pitch_rad.sin_cos();
    let (xs, ys) = g.norm_tables();
    let (w_lim, h_lim) = (w as f64 - 0.5, h as f64 - 0.5);
    // A row at a time: first where each pixel lands (no branch, so the divisions pack),
    // then the splats in pixel order, as one pass would make them.
    let (mut cell, mut landed) = (vec![u32::MAX; w], vec![0f64; w]);
    for (r, &y) in ys.iter().enumerate() {
        let depths = &src.depth_m[r * w..(r + 1) * w];
        for (i, (&x, &d)) in xs.iter().zip(depths).enumerate() {
            let d = d as f64;
            let t = if d.is_finite() && d > 0.0 { d } else { SKY_M };
            // `Geometry::reproject`, step for step, its `None` folded into `ok`.
            let (col, row, depth) = g.reproject_unchecked(sc, x, y, t, to_target);
            let ok = depth > IN_FRONT_M && col > -0.5 && row > -0.5 && col < w_lim && row < h_lim;
            let k = (nearest_i32(row) as u32)
                .wrapping_mul(w as u32)
                .wrapping_add(nearest_i32(col) as u32);
            cell[i] = if ok { k } else { u32::MAX };
            landed[i] = depth;
        }
        for (&k, &depth) in cell.iter().zip(&landed) {
            if k != u32::MAX && depth < z[k as usize] {
                z[k as usize] = depth;
            }
        }
    }
    // Cracks left by nearest-pixel splatting: the farthest neighbour's depth.
    // A disocclusion hole filled so fails the consistency test below, as it should.
    zf.clear();
    zf.extend_from_slice(&z);
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
    let mut fetch = WARP_FETCH.take();
    fetch.start(n);
    let from_target = x_t - src.x_m;
    let mut at = vec![(0f64, 0f64); w];
    for (r, &y) in ys.iter().enumerate() {
        // As the forward pass: where each pixel lands first, without a branch.
        for (i, (&x, &t)) in xs.iter().zip(&zf[r * w..(r + 1) * w]).enumerate() {
            let (col, row, depth) = g.reproject_unchecked(sc, x, y, t, from_target);
            let ok = t.is_finite() && depth > IN_FRONT_M && g.inside(col, row);
            let c = (nearest_i32(col) as u32).min(w as u32 - 1);
            let rr = (nearest_i32(row) as u32).min(h as u32 - 1);
            cell[i] = if ok { rr * w as u32 + c } else { u32::MAX };
            landed[i] = depth;
            at[i] = (col, row);
        }
        for (i, ((&s, &depth), &(col, row))) in cell.iter().zip(&landed).zip(&at).enumerate() {
            if s == u32::MAX {
                continue;
            }
            let ds = src.depth_m[s as usize] as f64;
            let ds = if ds.is_finite() && ds > 0.0 {
                ds
            } else {
                SKY_M
            };
            let agree = if depth > 0.5 * SKY_M {
                ds > 0.5 * SKY_M
            } else {
                (ds - depth).abs() <= crate::core::closedloop::seen_tolerance_m(depth)
            };
            fetch.push_if(agree, r * w + i, col, row);
        }
    }
    // The samples in a loop of their own: between the tests above each waited on the one
    // before; on their own the next sample's loads start while this one sums.
    let (ats, cols, rows) = fetch.padded();
    let lanes = cols
        .chunks_exact(Tap::LANES)
        .zip(rows.chunks_exact(Tap::LANES));
    for (at, (col, row)) in ats.chunks(Tap::LANES).zip(lanes) {
        let cols = Tap::at_lanes(col.try_into().expect("a lane each"), g.width);
        let rows = Tap::at_lanes(row.try_into().expect("a lane each"), g.height);
        #[cfg(target_arch = "x86_64")]
        if AVX2 {
            // SAFETY: `AVX2` is true only in `warp_one_avx2`, taken where the CPU has it.
            let values = unsafe { sample_lanes_avx2(g, &src.lum, &cols, &rows) };
            for (&k, v) in at.iter().zip(values) {
                lum[k] = v;
                valid[k] = true;
            }
            continue;
        }
        for (l, &k) in at.iter().enumerate() {
            lum[k] = g.sample_taps(&src.lum, cols.tap(l), rows.tap(l));
            valid[k] = true;
        }
    }
    WARP_FETCH.set(fetch);
    WARP_DEPTHS.set((z, zf));
    (lum, valid)
}

/// [`Geometry::sample_taps`] at [`Tap::LANES`] (eight) positions at once, each lane the same
/// bits: every tap's pixel clamped to the image (inside it, the pixels the unclamped taps
/// read), gathered eight at a time, and the same products summed in the same order from zero,
/// a tap at a time across the lanes (a multiply and an add, never fused). The warp's samples
/// took 7.4–8.0 s of `alfd eval --scene tree` one pixel at a time and take 6.0 s so (each
/// lane's four taps of a row as one load, transposed, took 8.6 s).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn sample_lanes_avx2(
    g: &Geometry,
    img: &[f32],
    cols: &TapLanes,
    rows: &TapLanes,
) -> [f32; Tap::LANES] {
    use std::arch::x86_64::*;
    let n = g.width * g.height;
    // Every gathered index is below `n` (clamped below), so inside `img`.
    assert!(
        img.len() >= n && n <= i32::MAX as usize,
        "image of the geometry's size"
    );
    // SAFETY (each load): eight values from an array of eight.
    let lanes = |v: &[i32; 8]| unsafe { _mm256_loadu_si256(v.as_ptr().cast()) };
    let weights = |taps: &TapLanes, d: usize| unsafe { _mm256_loadu_ps(taps.weights[d].as_ptr()) };
    let (col0, row0) = (lanes(&cols.first), lanes(&rows.first));
    let zero = _mm256_setzero_si256();
    let (w_last, h_last) = (
        _mm256_set1_epi32(g.width as i32 - 1),
        _mm256_set1_epi32(g.height as i32 - 1),
    );
    let width = _mm256_set1_epi32(g.width as i32);
    let clamp = |v: __m256i, last: __m256i| _mm256_min_epi32(_mm256_max_epi32(v, zero), last);
    let col_at: [__m256i; 4] = std::array::from_fn(|d| {
        clamp(
            _mm256_add_epi32(col0, _mm256_set1_epi32(d as i32 - 1)),
            w_last,
        )
    });
    let wc: [__m256; 4] = std::array::from_fn(|d| weights(cols, d));
    let mut acc = _mm256_setzero_ps();
    for dr in 0..4 {
        let row = clamp(
            _mm256_add_epi32(row0, _mm256_set1_epi32(dr as i32 - 1)),
            h_last,
        );
        let base = _mm256_mullo_epi32(row, width);
        let mut s = _mm256_setzero_ps();
        for (at, wx) in col_at.iter().zip(&wc) {
            let idx = _mm256_add_epi32(base, *at);
            // SAFETY: every index is a clamped row times the width plus a clamped column,
            // below `n <= img.len()` (asserted above).
            let v = unsafe { _mm256_i32gather_ps::<4>(img.as_ptr(), idx) };
            s = _mm256_add_ps(s, _mm256_mul_ps(*wx, v));
        }
        acc = _mm256_add_ps(acc, _mm256_mul_ps(weights(rows, dr), s));
    }
    let mut out = [0f32; 8];
    // SAFETY: an unaligned store of eight `f32`s into an array of eight.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), acc) };
    out
}

/// [`warp_one`]'s pixels to sample: each one's index and its source column and row, a list
/// each, so that [`Tap::LANES`] of them are one load. Sized for every pixel and written
/// whether a pixel is kept or not, the count moving on only when it is (no branch).
#[derive(Default)]
struct Fetch {
    at: Vec<usize>,
    col: Vec<f64>,
    row: Vec<f64>,
    len: usize,
}

impl Fetch {
    const fn new() -> Fetch {
        Fetch {
            at: Vec::new(),
            col: Vec::new(),
            row: Vec::new(),
            len: 0,
        }
    }

    /// Empty, with room for `n` pixels and the padding.
    fn start(&mut self, n: usize) {
        let room = n + Tap::LANES;
        self.at.resize(room, 0);
        self.col.resize(room, 0.0);
        self.row.resize(room, 0.0);
        self.len = 0;
    }

    /// Writes the pixel at the end and keeps it there if `keep`. At most `n` (of
    /// [`Self::start`]) calls.
    #[inline(always)]
    fn push_if(&mut self, keep: bool, at: usize, col: f64, row: f64) {
        let m = self.len;
        self.at[m] = at;
        self.col[m] = col;
        self.row[m] = row;
        self.len += usize::from(keep);
    }

    /// The indices kept, and their columns and rows padded with zeros to whole
    /// [`Tap::LANES`]: the padding's lanes are sampled and not stored.
    fn padded(&mut self) -> (&[usize], &[f64], &[f64]) {
        let end = self.len.next_multiple_of(Tap::LANES);
        self.col[self.len..end].fill(0.0);
        self.row[self.len..end].fill(0.0);
        (&self.at[..self.len], &self.col[..end], &self.row[..end])
    }
}

thread_local! {
    /// [`warp_one`]'s pixels to sample, kept between calls.
    static WARP_FETCH: std::cell::Cell<Fetch> = const { std::cell::Cell::new(Fetch::new()) };
    /// [`warp_one`]'s z-buffer and its crack-filled copy, kept between calls: freshly
    /// allocated for each of `alfd eval`'s thousands of warps, their pages were returned to
    /// the system and faulted in again.
    static WARP_DEPTHS: std::cell::Cell<(Vec<f64>, Vec<f64>)> =
        const { std::cell::Cell::new((Vec::new(), Vec::new())) };
}

/// A capture's warp ([`warp_one`]): its luminance at the target and which pixels it fills.
type Warped = (Vec<f32>, Vec<bool>);

/// Warps kept for reuse, the most recently used up to [`Warps::BYTES_MAX`], keyed by the
/// positions of the capture and the target along the line. One view is rendered from many
/// pairs of captures (the sweeps' spacings, each plan of a search), and a capture neighbours
/// the same view in several: on `tree` 22,214 warps were made, 15,035 different, and over
/// half of the 7,179 repeats came within 400 warps of the one before (a sweep's spacings one
/// after another). A warp is a function of the two positions alone, so what is kept changes no
/// result. For one line's views: a new scene needs its own.
#[derive(Debug)]
pub struct Warps {
    bytes_max: usize,
    kept: std::sync::Mutex<KeptWarps>,
}

impl Default for Warps {
    fn default() -> Warps {
        Warps::holding(Warps::BYTES_MAX)
    }
}

#[derive(Debug, Default)]
struct KeptWarps {
    /// Uses so far: a warp's stamp is its last use.
    uses: u64,
    /// Warps made (not taken from those kept).
    made: usize,
    bytes: usize,
    by_position: std::collections::HashMap<(u64, u64), (u64, std::sync::Arc<Warped>)>,
}

impl Warps {
    /// Bytes of warps kept at most (about 400 warps at 200 × 150); past it the least
    /// recently used is dropped.
    pub const BYTES_MAX: usize = 64 << 20;

    /// Keeping up to `bytes_max` bytes of warps.
    pub fn holding(bytes_max: usize) -> Warps {
        Warps {
            bytes_max,
            kept: Default::default(),
        }
    }

    /// Warps made so far, not taken from those kept.
    pub fn made(&self) -> usize {
        self.kept.lock().expect("not poisoned").made
    }

    /// `src` warped to `x_t`, kept or made (and then kept).
    fn get_or_make(&self, g: &Geometry, src: &View, x_t: f64) -> std::sync::Arc<Warped> {
        let key = (src.x_m.to_bits(), x_t.to_bits());
        {
            let mut kept = self.kept.lock().expect("not poisoned");
            kept.uses += 1;
            let uses = kept.uses;
            if let Some((stamp, w)) = kept.by_position.get_mut(&key) {
                *stamp = uses;
                return w.clone();
            }
        }
        let w = std::sync::Arc::new(warp_one(g, src, x_t));
        let bytes = w.0.len() * 4 + w.1.len();
        let mut kept = self.kept.lock().expect("not poisoned");
        kept.made += 1;
        while kept.bytes + bytes > self.bytes_max {
            let Some(oldest) = kept
                .by_position
                .iter()
                .min_by_key(|(_, v)| v.0)
                .map(|(k, _)| *k)
            else {
                break;
            };
            let (_, gone) = kept.by_position.remove(&oldest).expect("just found");
            kept.bytes -= gone.0.len() * 4 + gone.1.len();
        }
        if kept.bytes + bytes <= self.bytes_max {
            kept.uses += 1;
            let stamp = kept.uses;
            if kept.by_position.insert(key, (stamp, w.clone())).is_none() {
                kept.bytes += bytes;
            }
        }
        w
    }
}

/// (b) Depth-aided warping; pixels neither neighbour sees fall back to (a).
pub fn warp(g: &Geometry, a: &View, b: &View, x_t: f64, w_opt_per_m: f64) -> Vec<f32> {
    let [_, warped] = both(g, a, b, x_t, w_opt_per_m);
    warped
}

/// Both renderings, `[(a), (b)]`: the warp's fallback is the light field already made.
pub fn both(g: &Geometry, a: &View, b: &View, x_t: f64, w_opt_per_m: f64) -> [Vec<f32>; 2] {
    both_kept(g, a, b, x_t, w_opt_per_m, None)
}

/// [`both`], each capture's warp taken from `warps` where kept there, and kept there when
/// made (the views must be one line's: a warp is keyed by the positions alone).
pub fn both_kept(
    g: &Geometry,
    a: &View,
    b: &View,
    x_t: f64,
    w_opt_per_m: f64,
    warps: Option<&Warps>,
) -> [Vec<f32>; 2] {
    let field = lightfield(g, a, b, x_t, w_opt_per_m);
    let warp = |src: &View| match warps {
        Some(kept) => kept.get_or_make(g, src, x_t),
        None => std::sync::Arc::new(warp_one(g, src, x_t)),
    };
    let (wa_, wb_) = (warp(a), warp(b));
    let (la, va) = (&wa_.0, &wa_.1);
    let (lb, vb) = (&wb_.0, &wb_.1);
    let wa = weight_a(a, b, x_t);
    let mut out = vec![0f32; g.width * g.height];
    for (k, o) in out.iter_mut().enumerate() {
        *o = match (va[k], vb[k]) {
            (true, true) => wa * la[k] + (1.0 - wa) * lb[k],
            (true, false) => la[k],
            (false, true) => lb[k],
            (false, false) => field[k],
        };
    }
    [field, out]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eight taps at once are each [`Tap::at`]'s, bit for bit: across an axis, at and
    /// beyond both ends (clamped), at whole and half pixels and between.
    #[test]
    fn taps_in_lanes_are_the_taps_one_at_a_time() {
        for n in [1usize, 2, 7, 200, 1280] {
            let mut xs: Vec<f64> = (0..4000)
                .map(|k| -3.0 + k as f64 * (n as f64 + 6.0) / 4000.0)
                .collect();
            xs.extend([
                -0.5,
                0.0,
                0.5,
                n as f64 - 1.0,
                n as f64 - 0.5,
                1e300,
                -1e300,
            ]);
            xs.extend((0..n.min(50)).flat_map(|i| [i as f64, i as f64 + 0.5, i as f64 + 0.25]));
            for chunk in xs.chunks(Tap::LANES) {
                let x = std::array::from_fn(|l| chunk.get(l).copied().unwrap_or(0.0));
                let taps = Tap::at_lanes(x, n);
                for (l, &x) in x.iter().enumerate() {
                    let (tap, one) = (taps.tap(l), Tap::at(x, n));
                    assert_eq!(tap.first, one.first, "n {n} x {x}");
                    assert_eq!(
                        tap.weights.map(f32::to_bits),
                        one.weights.map(f32::to_bits),
                        "n {n} x {x}"
                    );
                }
            }
        }
    }

    /// What the reference per-pixel light field met: pixels off both captures, and
    /// pixels where the plane is behind a capture.
    #[derive(Default)]
    struct Met {
        off_both: usize,
        behind: usize,
    }

    /// The light field pixel by pixel, each pixel projected into both captures, as it was
    /// computed before [`Plane`] projected the columns and rows once.
    fn lightfield_per_pixel(
        g: &Geometry,
        a: &View,
        b: &View,
        x_t: f64,
        w_opt_per_m: f64,
        met: &mut Met,
    ) -> Vec<f32> {
        let sc = g.pitch_rad.sin_cos();
        let t = if w_opt_per_m > 1.0 / SKY_M {
            1.0 / w_opt_per_m
        } else {
            SKY_M
        };
        let wa = weight_a(a, b, x_t);
        let mut out = Vec::with_capacity(g.width * g.height);
        for r in 0..g.height {
            for i in 0..g.width {
                let (x, y) = g.norm(i, r);
                let sample = |v: &View| {
                    g.reproject(sc, x, y, t, x_t - v.x_m)
                        .filter(|p| g.inside(p.0, p.1))
                        .map(|p| g.sample(&v.lum, p.0, p.1))
                };
                out.push(match (sample(a), sample(b)) {
                    (Some(va), Some(vb)) => wa * va + (1.0 - wa) * vb,
                    (Some(va), None) => va,
                    (None, Some(vb)) => vb,
                    (None, None) => {
                        met.off_both += 1;
                        let v = if wa >= 0.5 { a } else { b };
                        match g.reproject(sc, x, y, t, x_t - v.x_m) {
                            Some(p) => g.sample(&v.lum, p.0, p.1),
                            None => {
                                met.behind += 1;
                                v.lum[r * g.width + i]
                            }
                        }
                    }
                });
            }
        }
        out
    }

    /// A view whose luminance is a fixed pseudo-random pattern.
    fn view(x_m: f64, g: &Geometry, seed: u32) -> View {
        let lum = (0..g.width * g.height)
            .map(|k| {
                let h = (k as u32 ^ seed)
                    .wrapping_mul(2_654_435_761)
                    .rotate_left(13);
                (h % 10_007) as f32 / 10_007.0
            })
            .collect();
        View {
            x_m,
            lum,
            depth_m: vec![10.0; g.width * g.height],
        }
    }

    /// The AVX2 build of the warp (taken on this machine when it has AVX2) gives the portable
    /// build's bits: each view of the test line warped into its neighbours and beyond.
    #[test]
    fn the_avx2_warp_is_the_portable_warp_bit_for_bit() {
        let (_, g, views) = crate::eval::tests::views();
        let (mut valid_px, mut invalid_px) = (0, 0);
        for (src, t) in [(0, 1), (4, 2), (4, 6), (8, 3), (2, 2)] {
            let x_t = views[t].x_m + 0.1;
            let (lum, valid) = warp_one(&g, &views[src], x_t);
            let (want_lum, want_valid) = warp_one_with::<false>(&g, &views[src], x_t);
            assert_eq!(valid, want_valid, "{src} into {t}");
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&lum), bits(&want_lum), "{src} into {t}");
            valid_px += valid.iter().filter(|&&v| v).count();
            invalid_px += valid.iter().filter(|&&v| !v).count();
        }
        // Pixels fetched, and holes (disoccluded or out of the source's frame).
        assert!(
            valid_px > 0 && invalid_px > 0,
            "{valid_px} valid, {invalid_px} not"
        );
    }

    /// Warps taken from those kept are the warps made afresh, bit for bit, and the one
    /// dropped at the limit is the least recently used.
    #[test]
    fn kept_warps_are_made_afresh_and_the_least_recently_used_goes() {
        let (_, g, views) = crate::eval::tests::views();
        let one = g.width * g.height * 5;
        // Room for two warps.
        let warps = Warps::holding(2 * one + one / 2);
        let x_t = views[3].x_m + 0.1;
        let bits = |w: &Warped| {
            (
                w.0.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                w.1.clone(),
            )
        };
        // (source, warps made after the request): A, B, A kept, C drops B (not A, used
        // since), A kept, B made again.
        for (src, made) in [(2, 1), (4, 2), (2, 2), (5, 3), (2, 3), (4, 4)] {
            let kept = warps.get_or_make(&g, &views[src], x_t);
            assert_eq!(
                bits(&kept),
                bits(&warp_one(&g, &views[src], x_t)),
                "source {src}"
            );
            assert_eq!(warps.made(), made, "after source {src}");
        }
        // Positions: the same source to another target is another warp.
        warps.get_or_make(&g, &views[2], x_t + 0.5);
        assert_eq!(warps.made(), 5);
    }

    #[test]
    fn nearest_is_round_half_away_saturated_at_zero() {
        let want = |x: f64| x.round().max(0.0) as usize;
        let mut xs = vec![-0.5, -0.49999999999999994, -0.25, -0.0, 0.0, 0.5, 1.5, 2.5];
        xs.extend([0.49999999999999994, 1.4999999999999998, 2.4999999999999996]);
        xs.extend([
            199.5,
            199.49999999999997,
            2147483646.5,
            2147483645.5,
            2147483646.4999998,
        ]);
        let mut s = 7u64;
        for _ in 0..100_000 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let x = (s >> 11) as f64 / (1u64 << 53) as f64 * 700.0 - 0.5;
            let half = x.floor() + 0.5;
            xs.extend([x, half, half.next_down(), half.next_up()]);
        }
        for x in xs.into_iter().filter(|&x| x >= -0.5) {
            assert_eq!(nearest_i32(x) as usize, want(x), "{x:e}");
        }
    }

    #[test]
    fn the_plane_projected_by_column_and_row_is_the_per_pixel_light_field_bit_for_bit() {
        let mut met = Met::default();
        for pitch_rad in [0.0, 0.35, -0.6] {
            let g = Geometry {
                width: 23,
                height: 17,
                focal_px: 19.0,
                cx_px: 11.0,
                cy_px: 9.3,
                pitch_rad,
            };
            let (a, b) = (view(-1.0, &g, 1), view(2.5, &g, 2));
            // Between the captures, on them, beyond them; the plane at the sky, far, near,
            // and near enough to be behind a capture once the camera is tilted.
            for x_t in [-3.0, -1.0, 0.0, 1.7, 2.5, 4.0] {
                for w_opt_per_m in [1e-7, 0.02, 0.5, 3.0] {
                    let fast = lightfield(&g, &a, &b, x_t, w_opt_per_m);
                    let slow = lightfield_per_pixel(&g, &a, &b, x_t, w_opt_per_m, &mut met);
                    for (k, (f, s)) in fast.iter().zip(&slow).enumerate() {
                        assert_eq!(
                            f.to_bits(),
                            s.to_bits(),
                            "pixel {k}, pitch {pitch_rad}, x_t {x_t}, w {w_opt_per_m}: {f} vs {s}"
                        );
                    }
                }
            }
        }
        assert!(
            met.off_both > 0 && met.behind > 0,
            "{} off both, {} behind",
            met.off_both,
            met.behind
        );
    }
}
