//! Where the open loop's parallax and the truth's part: for in-between views
//! along a stretch of a scene's survey line, the quality model's open-loop
//! parallax at a spacing (from the view's own sensor depth), the same span
//! recomputed over all of the view's surface pixels and over only those both
//! neighbouring captures see (linearised and exact), and the truth's figure
//! (`docs/eval.md`, sixth session):
//! `cargo run --release --example parallax_pixel_sets -- scenes/orchard.toml -8.4 0.4 0.8`
//! (scene, first and last capture position along the line in metres, spacing).

use alfd::core::Estimator;
use alfd::eval::recon::{Geometry, View};
use alfd::eval::truth::{Truth, BOTH, PARALLAX_PERCENTILES};
use alfd::eval::{eval_sensor, quality_params};
use alfd::render::{render, survey_camera, RenderOptions};
use alfd::scene::Scene;
use anyhow::Context;
use std::path::PathBuf;

/// The ends of the truth's robust span ([`PARALLAX_PERCENTILES`], the same ranks).
fn span(mut v: Vec<f64>) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let at = |p: f64| v[(p * (v.len() - 1) as f64).round() as usize];
    Some((at(PARALLAX_PERCENTILES.0), at(PARALLAX_PERCENTILES.1)))
}

fn show(s: Option<(f64, f64)>) -> String {
    s.map_or("–".into(), |(lo, hi)| {
        format!("{lo:.3}–{hi:.3} = {:.3}", hi - lo)
    })
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().unwrap_or_else(|| "scenes/orchard.toml".into()));
    let mut num = |default: f64| -> anyhow::Result<f64> {
        args.next()
            .map_or(Ok(default), |a| a.parse().context("a number (metres)"))
    };
    let (from_m, to_m, spacing_m) = (num(-8.4)?, num(0.4)?, num(0.8)?);
    let scene = Scene::load(&path)?;
    let s = scene.survey.clone();
    let (w, h) = (s.width, s.height);
    let g = Geometry::of_survey(&scene, w, h);
    let (f, cx, cy) = (g.focal_px, g.cx_px, g.cy_px);
    let intr = alfd::core::Intrinsics::from_focal_px(w, h, f, Some((cx, cy)))?;
    let sensor = eval_sensor();
    let mut est = Estimator::new(quality_params());
    let step = s.view_step_m;
    let half = ((spacing_m / 2.0) / step).round().max(1.0) as usize;
    let n = ((to_m - from_m) / step).round() as usize + 1;
    let mut views = Vec::with_capacity(n);
    let mut open = Vec::with_capacity(n);
    for k in 0..n {
        let x = from_m + k as f64 * step;
        let frame = render(
            &scene,
            &survey_camera(&scene, x, w, h),
            &RenderOptions { supersample: 2 },
        );
        let e = est.estimate_at(&frame.z16(&sensor), &intr, g.pitch_rad, 1)?;
        open.push(
            e.predict_at(2.0 * half as f64 * step)
                .and_then(|p| p.parallax_px),
        );
        views.push(View {
            x_m: x,
            lum: frame.luminance(),
            depth_m: frame.depth_m,
        });
    }
    let truth = Truth::new(&scene, g);
    let (sin, cos) = s.pitch_rad.sin_cos();
    let b = 2.0 * half as f64 * step;
    println!(
        "{}: spacing {b:.2} m; per in-between view: open loop | all surface pixels | pixels both captures see (linearised / exact) | truth; pixels seen by one capture",
        scene.name
    );
    for k in (half..n - half).step_by(half) {
        let c = truth.classify(&views[k], &views[k - half], &views[k + half], false);
        let (mut all, mut both, mut exact) = (Vec::new(), Vec::new(), Vec::new());
        for r in 0..h {
            for i in 0..w {
                let t = views[k].depth_m[r * w + i] as f64;
                if !(t.is_finite() && t > 0.0) {
                    continue;
                }
                let (u, v) = (i as f64 + 0.5 - cx, r as f64 + 0.5 - cy);
                // The estimator's per-pixel gain off nadir, `|(f·cos φ − u·sin φ, v·sin φ)|`.
                let linear = ((f * cos - u * sin).powi(2) + (v * sin).powi(2)).sqrt() / t * b;
                all.push(linear);
                if c.class[r * w + i] == BOTH {
                    both.push(linear);
                    // Exact: the pixel's point reprojected into both captures.
                    let at = |delta: f64| {
                        let d = t + delta * sin;
                        ((u * t / f + delta * cos) / d * f, v * t / f / d * f)
                    };
                    let (p, q) = (at(-b / 2.0), at(b / 2.0));
                    exact.push(((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt());
                }
            }
        }
        println!(
            "x {:7.2} m: {} | {} | {} / {} | {} ; {}",
            views[k].x_m,
            open[k].map_or("–".into(), |p| format!("{p:.3}")),
            show(span(all)),
            show(span(both)),
            show(span(exact)),
            c.parallax_span_px.map_or("–".into(), |p| format!("{p:.3}")),
            c.counts[1]
        );
    }
    Ok(())
}
