//! Where the open loop's views per point and the truth's part: for one view of a
//! scene's survey line, each surface pixel of the middle half across track (the
//! truth's sample), its visibility along the line by exact ray casting (the truth:
//! `eval::truth::Truth::visibility`) against the quality model's interval from the
//! view's own sensor depth (`core::visibility::line_intervals`, the sweep the
//! estimator runs). Prints the pixels with the shortest true visibility and the
//! estimator's shortest, each with the other's figure (`docs/eval.md`):
//! `cargo run --release --example views_per_point_pixels -- scenes/orchard.toml -20`
//! (scene, view position along the line in metres).

use alfd::core::inverse::{fill_grid, DepthRange, InvGrid};
use alfd::core::visibility::{line_intervals, Interval, LineScratch, TrackRays, VisibilityParams};
use alfd::core::TrackAxis;
use alfd::eval::recon::Geometry;
use alfd::eval::truth::Truth;
use alfd::eval::{eval_sensor, quality_params, VPP_STEP_M};
use alfd::render::{render, survey_camera, RenderOptions};
use alfd::scene::Scene;
use anyhow::Context;
use std::path::PathBuf;

/// A pixel: column, row, surface point, true visibility (m), the true run
/// around the view (m from it), the number of runs, the sweep's interval.
type Row = (
    usize,
    usize,
    [f64; 3],
    f64,
    (f64, f64),
    usize,
    Option<Interval>,
);

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().unwrap_or_else(|| "scenes/orchard.toml".into()));
    let x_m: f64 = args
        .next()
        .map_or(Ok(-20.0), |a| a.parse().context("a position (m)"))?;
    let scene = Scene::load(&path)?;
    let s = scene.survey.clone();
    let (w, h) = (s.width, s.height);
    let cam = survey_camera(&scene, x_m, w, h);
    let g = Geometry::of_survey(&scene, w, h);
    let (f, cx, cy) = (g.focal_px, g.cx_px, g.cy_px);
    let intr = alfd::core::Intrinsics::from_focal_px(w, h, f, Some((cx, cy)))?;
    let frame = render(&scene, &cam, &RenderOptions { supersample: 2 });
    let img = frame.z16(&eval_sensor());
    let params = quality_params();
    let k = params.quality.views_per_point_min as f64;

    // The estimator's intervals, per pixel (rows run along track: line = row).
    let mut grid = InvGrid::default();
    fill_grid(&img, TrackAxis::Rows, 1, &DepthRange::default(), &mut grid);
    let geom = intr.track(TrackAxis::Rows);
    let rays = TrackRays::new(&geom, &grid.along_idx, s.pitch_rad);
    let mut scratch = LineScratch::default();
    let mut est: Vec<Option<Interval>> = vec![None; w * h];
    let mut out = Vec::new();
    for a in 0..grid.lines {
        line_intervals(
            grid.line(a),
            &rays,
            VisibilityParams::default().occluder_margin_rel,
            &mut scratch,
            &mut out,
        );
        let r = grid.across_idx[a];
        for (j, iv) in out.iter().enumerate() {
            est[r * w + grid.along_idx[j]] = *iv;
        }
    }

    // The truth's, over the middle half across track (its sample), every pixel.
    let truth = Truth::new(&scene, g);
    let max_m = 8.0 * s.altitude_m.max(1.0);
    let mut rows = Vec::new();
    for r in h / 4..h - h / 4 {
        for i in 0..w {
            let d = frame.depth_m[r * w + i] as f64;
            if !(d.is_finite() && d > 0.0) {
                continue;
            }
            let p = truth.point(x_m, i, r, d);
            let runs = truth.visibility(p, x_m, VPP_STEP_M, max_m);
            let true_m: f64 = runs.iter().map(|(a, b)| b - a).sum();
            let here = runs
                .iter()
                .find(|(a, b)| (a - 1e-6..=b + 1e-6).contains(&x_m))
                .map_or((0.0, 0.0), |(a, b)| (a - x_m, b - x_m));
            rows.push((i, r, p, true_m, here, runs.len(), est[r * w + i]));
        }
    }
    let show = |t: &Row| {
        let (i, r, p, true_m, here, runs, iv) = t;
        println!(
            "col {i:3} row {r:3}  point ({:7.2}, {:7.2}, {:5.2})  truth {true_m:6.2} m in {runs} run(s), {:+.2} … {:+.2} around the view  | estimator {}",
            p[0],
            p[1],
            p[2],
            here.0,
            here.1,
            iv.map_or("–".into(), |iv| format!(
                "{:6.2} m ({:+.2} … {:+.2}, ends {:?} / {:?})",
                iv.length_m(),
                iv.from_m,
                iv.to_m,
                iv.from,
                iv.to
            ))
        )
    };
    println!(
        "{} at x = {x_m} m: {} surface pixels in the middle half; views per point k = {k}",
        scene.name,
        rows.len()
    );
    rows.sort_by(|a, b| a.3.total_cmp(&b.3));
    println!("\nShortest true visibility (spacing = length / k):");
    rows.iter().take(12).for_each(show);
    let est_len = |t: &Row| t.6.map_or(f64::INFINITY, |iv| iv.length_m());
    rows.sort_by(|a, b| est_len(a).total_cmp(&est_len(b)));
    println!("\nShortest estimated interval:");
    rows.iter().take(12).for_each(show);
    Ok(())
}
