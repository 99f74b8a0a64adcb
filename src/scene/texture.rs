//! Procedural solid texture with a known bandwidth: a sum of plane waves in 3-D
//! whose spatial frequencies are at most `cutoff_per_m` cycles per metre, so on
//! any surface the texture has no content above the cut-off. The renderer
//! evaluates the same waves with a polynomial sine (within 4e-9 of the sum of
//! libm sines).

/// Number of plane waves per texture.
pub const WAVES: usize = 10;
// `pattern_fast` sums the ten waves as a fixed tree.
const _: () = assert!(WAVES == 10);

/// Points [`Texture::patterns_fast`] evaluates together: two AVX2 vectors, or
/// four SSE2 ones, per wave.
pub const BATCH: usize = 8;

/// Waves padded with zero ones to whole AVX2 vectors: a ten-lane loop ends in
/// a masked store, microcoded on AMD and a failed store-to-load forward when
/// the sum reads it back. The padding lanes are computed and never summed.
const LANES: usize = 12;

/// Adding then subtracting 1.5·2⁵² rounds an f64 of magnitude below 2⁵¹ to the
/// nearest integer: branch-free, vectorisable, and without the libm `floor`
/// call that baseline x86-64 (no SSE4.1 `roundpd`) would make.
const ROUND: f64 = 6_755_399_441_055_744.0;

/// Taylor coefficients of `sin(2π·q)` in odd powers of `q`, to `q¹³`: for
/// `|q| ≤ 1/4` the first omitted term, `(π/2)¹⁵/15!`, is below 7e-10.
const SIN_2PI: [f64; 7] = {
    const TAU: f64 = std::f64::consts::TAU;
    let mut c = [0.0; 7];
    let mut term = TAU; // (2π)^(2k+1) / (2k+1)!, alternating
    let mut k = 0;
    while k < 7 {
        c[k] = term;
        term = -term * TAU * TAU / (((2 * k + 2) * (2 * k + 3)) as f64);
        k += 1;
    }
    c
};

/// `sin(2π·u)` for `u` in cycles of magnitude below 2⁵¹: the offset from the
/// nearest whole cycle (r in [-1/2, 1/2]), folded to |q| ≤ 1/4 through
/// sin(2π·r) = sin(2π·(±1/2 − r)), then the polynomial. One sine for both
/// evaluations of the waves, so a point alone and in a batch meet the same
/// operations.
#[inline(always)]
fn sin_cycles(u: f64) -> f64 {
    let r = u - ((u + ROUND) - ROUND);
    let q = if r.abs() > 0.25 {
        0.5f64.copysign(r) - r
    } else {
        r
    };
    // Estrin's scheme in z = q²: a dependency chain of four multiplications
    // instead of Horner's seven multiply-adds.
    let c = &SIN_2PI;
    let z = q * q;
    let z2 = z * z;
    let z4 = z2 * z2;
    let lo = (c[0] + c[1] * z) + (c[2] + c[3] * z) * z2;
    let hi = (c[4] + c[5] * z) + c[6] * z2;
    q * (lo + hi * z4)
}

/// The ten waves' sines summed as a fixed tree (not a chain of ten dependent
/// additions), scaled to unit variance (each sine has variance 1/2).
#[inline(always)]
fn sum_waves(w: &[f64]) -> f64 {
    let v = ((w[0] + w[1]) + (w[2] + w[3])) + ((w[4] + w[5]) + (w[6] + w[7])) + (w[8] + w[9]);
    v * (2.0 / WAVES as f64).sqrt()
}

#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub colour: [f32; 3],
    pub contrast: f32,
    pub cutoff_per_m: f64,
    pub seed: u64,
    /// `(2π·f·direction, phase)`, `|f| ≤ cutoff_per_m`.
    waves: [([f64; 3], f64); WAVES],
    /// The same waves in cycles instead of radians (`f·direction`, phase/2π),
    /// one array per component so the dot products vectorise.
    cycles_k: [[f64; LANES]; 3],
    cycles_phase: [f64; LANES],
    /// Beyond this coordinate magnitude (metres) a wave's argument could leave
    /// the range where [`ROUND`] works; such points take the exact sines.
    fast_limit_m: f64,
}

fn splitmix(s: &mut u64) -> f64 {
    *s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *s;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

impl Texture {
    /// Waves with frequencies log-uniform in `[cutoff/8, cutoff]` and directions
    /// uniform on the sphere, drawn deterministically from `seed`.
    pub fn new(colour: [f32; 3], contrast: f32, cutoff_per_m: f64, seed: u64) -> Texture {
        let mut s = seed ^ 0xA5A5_5A5A_1234_5678;
        let waves: [([f64; 3], f64); WAVES] = std::array::from_fn(|_| {
            let f = cutoff_per_m * (1.0f64 / 8.0).powf(splitmix(&mut s));
            let z = 2.0 * splitmix(&mut s) - 1.0;
            let a = std::f64::consts::TAU * splitmix(&mut s);
            let r = (1.0 - z * z).max(0.0).sqrt();
            let k = std::f64::consts::TAU * f;
            let phase = std::f64::consts::TAU * splitmix(&mut s);
            ([k * r * a.cos(), k * r * a.sin(), k * z], phase)
        });
        let per_rad = 1.0 / std::f64::consts::TAU;
        // Lanes past the ten waves stay zero.
        let mut cycles_k = [[0.0; LANES]; 3];
        let mut cycles_phase = [0.0; LANES];
        for (j, (k, phase)) in waves.iter().enumerate() {
            for (c, kc) in k.iter().enumerate() {
                cycles_k[c][j] = kc * per_rad;
            }
            cycles_phase[j] = phase * per_rad;
        }
        // |argument| ≤ |k|₁·max|p| + 1 stays below 2⁵⁰ < 2⁵¹.
        let k1 = (0..WAVES)
            .map(|j| (0..3).map(|c| f64::abs(cycles_k[c][j])).sum::<f64>())
            .fold(0.0, f64::max);
        let fast_limit_m = if k1 > 0.0 {
            (1u64 << 49) as f64 / k1
        } else {
            f64::INFINITY
        };
        Texture {
            colour,
            contrast,
            cutoff_per_m,
            seed,
            waves,
            cycles_k,
            cycles_phase,
            fast_limit_m,
        }
    }

    /// Zero-mean pattern of unit variance (over space) at point `p`, metres:
    /// the definition, one libm sine per wave.
    #[inline]
    pub fn pattern(&self, p: [f64; 3]) -> f64 {
        let mut v = 0.0;
        for (k, ph) in &self.waves {
            v += (k[0] * p[0] + k[1] * p[1] + k[2] * p[2] + ph).sin();
        }
        // Each sine has variance 1/2.
        v * (2.0 / WAVES as f64).sqrt()
    }

    /// [`Texture::pattern`] from the same waves (so the same spectrum and
    /// cut-off), each sine by a polynomial after exact range reduction, within
    /// 7e-10 of the libm sine; every step vectorises.
    #[inline]
    pub fn pattern_fast(&self, p: [f64; 3]) -> f64 {
        let lim = self.fast_limit_m;
        // Written so that NaN also takes the exact path.
        if !(p[0].abs() < lim && p[1].abs() < lim && p[2].abs() < lim) {
            return self.pattern(p);
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above, cached by std).
            return unsafe { self.polynomial_waves_avx2(p) };
        }
        self.polynomial_waves(p)
    }

    /// [`Texture::polynomial_waves`] compiled for AVX2: four lanes instead of
    /// two. The same IEEE operations in the same order (no FMA), so the same
    /// bits as the portable build.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn polynomial_waves_avx2(&self, p: [f64; 3]) -> f64 {
        self.polynomial_waves(p)
    }

    #[inline(always)]
    fn polynomial_waves(&self, p: [f64; 3]) -> f64 {
        let [kx, ky, kz] = &self.cycles_k;
        let mut w = [0.0; LANES];
        for j in 0..LANES {
            // The argument in cycles.
            let u = kx[j] * p[0] + ky[j] * p[1] + kz[j] * p[2] + self.cycles_phase[j];
            w[j] = sin_cycles(u);
        }
        sum_waves(&w)
    }

    /// Points [`Texture::patterns_fast`] evaluates together.
    pub const BATCH: usize = BATCH;

    /// [`Texture::pattern_fast`] at [`BATCH`] points (coordinates one array
    /// per axis), each with the same bits as one call. The waves are the outer
    /// loop and the points the vector's lanes, so every point meets the same
    /// operations in the same order as in [`Texture::polynomial_waves`], and
    /// no lane is spent on padding waves or a sum across lanes.
    #[inline]
    pub fn patterns_fast(
        &self,
        x: &[f64; BATCH],
        y: &[f64; BATCH],
        z: &[f64; BATCH],
    ) -> [f64; BATCH] {
        let lim = self.fast_limit_m;
        let inside = (0..BATCH).all(|l| x[l].abs() < lim && y[l].abs() < lim && z[l].abs() < lim);
        // Written so that NaN also takes the one-point path (and its exact sines).
        if !inside {
            return std::array::from_fn(|l| self.pattern_fast([x[l], y[l], z[l]]));
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above, cached by std).
            return unsafe { self.polynomial_batch_avx2(x, y, z) };
        }
        self.polynomial_batch(x, y, z)
    }

    /// [`Texture::polynomial_batch`] compiled for AVX2 (the same operations,
    /// no FMA, so the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn polynomial_batch_avx2(
        &self,
        x: &[f64; BATCH],
        y: &[f64; BATCH],
        z: &[f64; BATCH],
    ) -> [f64; BATCH] {
        self.polynomial_batch(x, y, z)
    }

    #[inline(always)]
    fn polynomial_batch(
        &self,
        x: &[f64; BATCH],
        y: &[f64; BATCH],
        z: &[f64; BATCH],
    ) -> [f64; BATCH] {
        let [kx, ky, kz] = &self.cycles_k;
        let mut w = [[0.0; BATCH]; WAVES];
        for (j, wj) in w.iter_mut().enumerate() {
            let (kxj, kyj, kzj, phj) = (kx[j], ky[j], kz[j], self.cycles_phase[j]);
            for l in 0..BATCH {
                // Step for step `polynomial_waves`' (see there).
                let u = kxj * x[l] + kyj * y[l] + kzj * z[l] + phj;
                wj[l] = sin_cycles(u);
            }
        }
        std::array::from_fn(|l| sum_waves(&std::array::from_fn::<f64, WAVES, _>(|j| w[j][l])))
    }

    /// [`Texture::albedo`] at [`BATCH`] points, each with the same bits.
    #[inline]
    pub fn albedo_batch(
        &self,
        x: &[f64; BATCH],
        y: &[f64; BATCH],
        z: &[f64; BATCH],
    ) -> [[f32; 3]; BATCH] {
        if self.contrast == 0.0 {
            return [self.colour; BATCH];
        }
        self.patterns_fast(x, y, z).map(|v| self.modulate(v))
    }

    /// Albedo at `p`, each channel in `[0, 1]` (the renderer's: polynomial
    /// sines).
    #[inline]
    pub fn albedo(&self, p: [f64; 3]) -> [f32; 3] {
        if self.contrast == 0.0 {
            return self.colour;
        }
        self.modulate(self.pattern_fast(p))
    }

    /// Albedo at `p` from the exact sines (the reference renderer's).
    pub fn albedo_exact(&self, p: [f64; 3]) -> [f32; 3] {
        if self.contrast == 0.0 {
            return self.colour;
        }
        self.modulate(self.pattern(p))
    }

    #[inline]
    fn modulate(&self, pattern: f64) -> [f32; 3] {
        let m = (1.0 + self.contrast as f64 * pattern).max(0.0) as f32;
        [
            (self.colour[0] * m).min(1.0),
            (self.colour[1] * m).min(1.0),
            (self.colour[2] * m).min(1.0),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_polynomial_sines_follow_libm_near_and_far() {
        let t = Texture::new([0.5; 3], 0.5, 2.0, 7);
        let mut s = 1u64;
        let mut worst = |scale: f64| {
            let mut w: f64 = 0.0;
            for _ in 0..20_000 {
                let p = [0, 1, 2].map(|_| (2.0 * splitmix(&mut s) - 1.0) * scale);
                w = w.max((t.pattern_fast(p) - t.pattern(p)).abs());
            }
            w
        };
        // Ten waves, each within 7e-10, scaled by √(2/10); plus the rounding
        // of arguments of up to ~1e5 rad.
        for scale in [1.0, 1e2, 1e4] {
            let w = worst(scale);
            assert!(w < 1e-8, "{w} at {scale} m");
        }
        // At a million metres the arguments' own rounding (either way) is
        // ~1e-9 rad per wave.
        let w = worst(1e6);
        assert!(w < 1e-7, "{w} at 1e6 m");
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let mut s = 5u64;
            for _ in 0..10_000 {
                let p = [0, 1, 2].map(|_| (2.0 * splitmix(&mut s) - 1.0) * 500.0);
                // SAFETY: AVX2 checked just above.
                let wide = unsafe { t.polynomial_waves_avx2(p) };
                assert_eq!(wide.to_bits(), t.polynomial_waves(p).to_bits(), "{p:?}");
            }
        }
        // Past the rounding trick's range the libm sines are used, not garbage.
        let far = [1e300, 0.0, 0.0];
        assert_eq!(t.pattern_fast(far).to_bits(), t.pattern(far).to_bits());
    }

    #[test]
    fn a_batch_of_points_has_the_bits_of_one_point_at_a_time() {
        let t = Texture::new([0.5, 0.4, 0.3], 0.7, 3.0, 11);
        let mut s = 9u64;
        for scale in [1.0, 300.0, 1e5] {
            for _ in 0..2_000 {
                let pts: [[f64; 3]; BATCH] = std::array::from_fn(|_| {
                    [0, 1, 2].map(|_| (2.0 * splitmix(&mut s) - 1.0) * scale)
                });
                let (x, y, z) = (pts.map(|p| p[0]), pts.map(|p| p[1]), pts.map(|p| p[2]));
                let batch = t.patterns_fast(&x, &y, &z);
                let albedo = t.albedo_batch(&x, &y, &z);
                for (l, p) in pts.iter().enumerate() {
                    assert_eq!(batch[l].to_bits(), t.pattern_fast(*p).to_bits(), "{p:?}");
                    assert_eq!(albedo[l], t.albedo(*p), "{p:?}");
                }
                // The portable build, whatever the CPU: the same bits too.
                let portable = t.polynomial_batch(&x, &y, &z);
                assert_eq!(portable.map(f64::to_bits), batch.map(f64::to_bits));
            }
        }
        // One point past the fast range (or NaN) sends the batch the one-point way.
        let mut x = [1.0; BATCH];
        x[3] = 1e300;
        x[5] = f64::NAN;
        let (y, z) = ([2.0; BATCH], [-3.0; BATCH]);
        let batch = t.patterns_fast(&x, &y, &z);
        for l in 0..BATCH {
            assert_eq!(
                batch[l].to_bits(),
                t.pattern_fast([x[l], y[l], z[l]]).to_bits()
            );
        }
        let flat = Texture::new([0.2, 0.3, 0.4], 0.0, 1.0, 3);
        assert_eq!(flat.albedo_batch(&x, &y, &z), [[0.2, 0.3, 0.4]; BATCH]);
    }

    #[test]
    fn a_flat_texture_is_its_colour() {
        let t = Texture::new([0.2, 0.3, 0.4], 0.0, 1.0, 3);
        assert_eq!(t.albedo([1.0, 2.0, 3.0]), [0.2, 0.3, 0.4]);
        assert_eq!(t.albedo_exact([1.0, 2.0, 3.0]), [0.2, 0.3, 0.4]);
    }
}
