//! Procedural solid texture with a known bandwidth: a sum of plane waves in 3-D
//! whose spatial frequencies are at most `cutoff_per_m` cycles per metre, so on
//! any surface the texture has no content above the cut-off.

/// Number of plane waves per texture.
pub const WAVES: usize = 10;

#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub colour: [f32; 3],
    pub contrast: f32,
    pub cutoff_per_m: f64,
    pub seed: u64,
    /// `(2π·f·direction, phase)`, `|f| ≤ cutoff_per_m`.
    waves: Vec<([f64; 3], f64)>,
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
        let waves = (0..WAVES)
            .map(|_| {
                let f = cutoff_per_m * (1.0f64 / 8.0).powf(splitmix(&mut s));
                let z = 2.0 * splitmix(&mut s) - 1.0;
                let a = std::f64::consts::TAU * splitmix(&mut s);
                let r = (1.0 - z * z).max(0.0).sqrt();
                let k = std::f64::consts::TAU * f;
                let phase = std::f64::consts::TAU * splitmix(&mut s);
                ([k * r * a.cos(), k * r * a.sin(), k * z], phase)
            })
            .collect();
        Texture {
            colour,
            contrast,
            cutoff_per_m,
            seed,
            waves,
        }
    }

    /// Zero-mean pattern of unit variance (over space) at point `p`, metres.
    #[inline]
    pub fn pattern(&self, p: [f64; 3]) -> f64 {
        let mut v = 0.0;
        for (k, ph) in &self.waves {
            v += (k[0] * p[0] + k[1] * p[1] + k[2] * p[2] + ph).sin();
        }
        // Each sine has variance 1/2.
        v * (2.0 / WAVES as f64).sqrt()
    }

    /// Albedo at `p`, each channel in `[0, 1]`.
    #[inline]
    pub fn albedo(&self, p: [f64; 3]) -> [f32; 3] {
        if self.contrast == 0.0 {
            return self.colour;
        }
        let m = (1.0 + self.contrast as f64 * self.pattern(p)).max(0.0) as f32;
        [
            (self.colour[0] * m).min(1.0),
            (self.colour[1] * m).min(1.0),
            (self.colour[2] * m).min(1.0),
        ]
    }
}
