//! PSNR and SSIM: closed forms, and SSIM against a second, direct
//! implementation (every 11×11 window summed in 2-D, written here without the
//! library's separable filter).

// The direct implementation indexes windows as the definition writes them.
#![allow(clippy::needless_range_loop)]

use alfd::metrics::{gaussian_window, mse, psnr, ssim};

fn noise(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 33) as f64 / (1u64 << 31) as f64) as f32
        })
        .collect()
}

/// SSIM by the definition: for each window fully inside, weighted moments with
/// the 2-D Gaussian w(i,j) = g(i)·g(j) built from its own formula.
fn ssim_direct(a: &[f32], b: &[f32], w: usize, h: usize, peak: f64) -> f64 {
    let mut g = [[0f64; 11]; 11];
    let mut total = 0.0;
    for (i, row) in g.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            let (x, y) = (i as f64 - 5.0, j as f64 - 5.0);
            *v = (-(x * x + y * y) / (2.0 * 1.5 * 1.5)).exp();
            total += *v;
        }
    }
    let c1 = (0.01 * peak) * (0.01 * peak);
    let c2 = (0.03 * peak) * (0.03 * peak);
    let mut sum = 0.0;
    let mut count = 0;
    for r in 0..=h - 11 {
        for c in 0..=w - 11 {
            let (mut mx, mut my) = (0.0, 0.0);
            for i in 0..11 {
                for j in 0..11 {
                    let k = (r + i) * w + c + j;
                    let wt = g[i][j] / total;
                    mx += wt * a[k] as f64;
                    my += wt * b[k] as f64;
                }
            }
            let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
            for i in 0..11 {
                for j in 0..11 {
                    let k = (r + i) * w + c + j;
                    let wt = g[i][j] / total;
                    let (dx, dy) = (a[k] as f64 - mx, b[k] as f64 - my);
                    sxx += wt * dx * dx;
                    syy += wt * dy * dy;
                    sxy += wt * dx * dy;
                }
            }
            sum += ((2.0 * mx * my + c1) * (2.0 * sxy + c2))
                / ((mx * mx + my * my + c1) * (sxx + syy + c2));
            count += 1;
        }
    }
    sum / count as f64
}

#[test]
fn psnr_closed_forms() {
    let a = vec![0.5f32; 100];
    assert!(psnr(&a, &a, 1.0).is_infinite());
    // Every pixel off by 0.1: MSE = 0.01, PSNR = 20 dB at peak 1.
    let b = vec![0.6f32; 100];
    assert!((psnr(&a, &b, 1.0) - 20.0).abs() < 1e-5);
    // Peak 255, error of 1 everywhere: 48.1308 dB.
    let x = vec![100.0f32; 64];
    let y = vec![101.0f32; 64];
    assert!((psnr(&x, &y, 255.0) - 48.130803608679).abs() < 1e-9);
    assert!((mse(&x, &y) - 1.0).abs() < 1e-12);
}

#[test]
fn window_is_the_normalised_gaussian() {
    let g = gaussian_window();
    assert!((g.iter().sum::<f64>() - 1.0).abs() < 1e-15);
    assert!((g[5] / g[4] - (1.0 / (2.0 * 2.25f64)).exp()).abs() < 1e-12);
    assert_eq!(g[0], g[10]);
}

#[test]
fn ssim_closed_forms() {
    let a = noise(40 * 30, 1);
    assert!((ssim(&a, &a, 40, 30, 1.0).unwrap() - 1.0).abs() < 1e-12);
    // Constant images a and b: σ = 0, SSIM = (2ab + C1)/(a² + b² + C1).
    let x = vec![0.3f32; 20 * 20];
    let y = vec![0.6f32; 20 * 20];
    let c1 = 0.0001;
    let expected = (2.0 * 0.3 * 0.6 + c1) / (0.09 + 0.36 + c1);
    let got = ssim(&x, &y, 20, 20, 1.0).unwrap();
    assert!((got - expected).abs() < 1e-6, "{got} vs {expected}");
    // A negated texture around the same mean: structure term near -1.
    let neg: Vec<f32> = a.iter().map(|v| 1.0 - v).collect();
    assert!(ssim(&a, &neg, 40, 30, 1.0).unwrap() < -0.9);
    assert!(
        ssim(&a, &a, 10, 120, 1.0).is_none(),
        "narrower than the window"
    );
}

#[test]
fn ssim_matches_a_direct_implementation() {
    let (w, h) = (37, 29);
    let a = noise(w * h, 7);
    // b: a blurred, shifted, noisy version of a (a realistic reconstruction error).
    let n = noise(w * h, 9);
    let b: Vec<f32> = (0..w * h)
        .map(|k| {
            let k1 = if k % w + 1 < w { k + 1 } else { k };
            0.6 * a[k] + 0.3 * a[k1] + 0.1 * n[k]
        })
        .collect();
    for peak in [1.0, 2.0] {
        let fast = ssim(&a, &b, w, h, peak).unwrap();
        let slow = ssim_direct(&a, &b, w, h, peak);
        assert!((fast - slow).abs() < 1e-9, "{fast} vs {slow}");
        assert!(fast > 0.0 && fast < 0.99, "{fast}");
    }
}
