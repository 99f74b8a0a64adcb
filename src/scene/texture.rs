//! Procedural solid texture with a known bandwidth: a sum of plane waves in 3-D
//! whose spatial frequencies are at most `cutoff_per_m` cycles per metre, so on
//! any surface the texture has no content above the cut-off. The renderer
//! evaluates the same waves through a sine table (within 3e-8 of the exact sum).

use std::sync::LazyLock;

/// Number of plane waves per texture.
pub const WAVES: usize = 10;
// `pattern_fast` sums the ten waves as a fixed tree.
const _: () = assert!(WAVES == 10);

/// Table nodes per period of the sine. With a second-order Taylor step from
/// the nearest node (|e| ≤ π/1024) a wave is within e³/6 < 5e-9 of its sine.
const NODES: usize = 1024;

/// Adding then subtracting 1.5·2⁵² rounds an f64 of magnitude below 2⁵¹ to the
/// nearest integer, and leaves that integer (mod 2⁵¹) in the low mantissa bits:
/// branch-free and without a libm `floor` call on baseline x86-64.
const ROUND: f64 = 6_755_399_441_055_744.0;

/// `(sin, cos)` at the nodes `2π·i/NODES` (a fixed-size array, so a masked
/// index needs no bounds check).
static SIN_COS: LazyLock<Box<[[f64; 2]; NODES]>> = LazyLock::new(|| {
    Box::new(std::array::from_fn(|i| {
        let (s, c) = (std::f64::consts::TAU * i as f64 / NODES as f64).sin_cos();
        [s, c]
    }))
});

#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub colour: [f32; 3],
    pub contrast: f32,
    pub cutoff_per_m: f64,
    pub seed: u64,
    /// `(2π·f·direction, phase)`, `|f| ≤ cutoff_per_m`.
    waves: [([f64; 3], f64); WAVES],
    /// The same waves in table nodes instead of radians, one array per
    /// component so the dot products vectorise.
    nodes_k: [[f64; WAVES]; 3],
    nodes_phase: [f64; WAVES],
    /// Beyond this coordinate magnitude (metres) a wave's argument could leave
    /// the range where [`ROUND`] works; such points take the exact sines.
    table_limit_m: f64,
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
        let per_rad = NODES as f64 / std::f64::consts::TAU;
        let nodes_k = std::array::from_fn(|c| std::array::from_fn(|j| waves[j].0[c] * per_rad));
        let nodes_phase = std::array::from_fn(|j| waves[j].1 * per_rad);
        // |argument| ≤ |k|₁·max|p| + NODES stays below 2⁵⁰ < 2⁵¹.
        let k1 = (0..WAVES)
            .map(|j| (0..3).map(|c| f64::abs(nodes_k[c][j])).sum::<f64>())
            .fold(0.0, f64::max);
        let table_limit_m = if k1 > 0.0 {
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
            nodes_k,
            nodes_phase,
            table_limit_m,
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

    /// [`Texture::pattern`] through the sine table: the same waves (so the same
    /// spectrum and cut-off), each within 5e-9 of its exact sine.
    #[inline]
    pub fn pattern_fast(&self, p: [f64; 3]) -> f64 {
        if !(p[0].abs().max(p[1].abs()).max(p[2].abs()) < self.table_limit_m) {
            return self.pattern(p);
        }
        let table: &[[f64; 2]; NODES] = &SIN_COS;
        let step_rad = std::f64::consts::TAU / NODES as f64;
        let [kx, ky, kz] = &self.nodes_k;
        // Separate passes over the waves, so the arithmetic ones vectorise and
        // only the table reads stay scalar.
        let mut u = [0.0; WAVES];
        for j in 0..WAVES {
            u[j] = kx[j] * p[0] + ky[j] * p[1] + kz[j] * p[2] + self.nodes_phase[j];
        }
        let mut e = [0.0; WAVES];
        let mut node = [0usize; WAVES];
        for j in 0..WAVES {
            let r = u[j] + ROUND;
            e[j] = (u[j] - (r - ROUND)) * step_rad;
            node[j] = (r.to_bits() as usize) & (NODES - 1);
        }
        let mut w = [0.0; WAVES];
        for j in 0..WAVES {
            let [s, c] = table[node[j]];
            // sin(x₀ + e) ≈ sin x₀ + e·cos x₀ − e²/2·sin x₀.
            w[j] = s + e[j] * (c - 0.5 * e[j] * s);
        }
        // A tree, not a chain of ten dependent additions.
        let v = ((w[0] + w[1]) + (w[2] + w[3])) + ((w[4] + w[5]) + (w[6] + w[7])) + (w[8] + w[9]);
        v * (2.0 / WAVES as f64).sqrt()
    }

    /// Albedo at `p`, each channel in `[0, 1]` (the renderer's, through the
    /// sine table).
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
    fn the_table_follows_the_exact_sines_everywhere_and_far_away() {
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
        // Ten waves, each within 5e-9, scaled by √(2/10).
        for scale in [1.0, 1e2, 1e4] {
            let w = worst(scale);
            assert!(w < 3e-8, "{w} at {scale} m");
        }
        // At a million metres the arguments' own rounding (either way) is
        // ~1e-9 rad per wave.
        let w = worst(1e6);
        assert!(w < 1e-7, "{w} at 1e6 m");
        // Past the table's range the exact sines are used, not garbage.
        let far = [1e300, 0.0, 0.0];
        assert_eq!(t.pattern_fast(far).to_bits(), t.pattern(far).to_bits());
    }

    #[test]
    fn a_flat_texture_is_its_colour() {
        let t = Texture::new([0.2, 0.3, 0.4], 0.0, 1.0, 3);
        assert_eq!(t.albedo([1.0, 2.0, 3.0]), [0.2, 0.3, 0.4]);
        assert_eq!(t.albedo_exact([1.0, 2.0, 3.0]), [0.2, 0.3, 0.4]);
    }
}
