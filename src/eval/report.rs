//! `results.json`, `report.md` and `decimation.md` of `alfd eval`.

use super::{calibrate_occlusion_max, SceneResult, METHODS, RENDERERS, SETTINGS};
use crate::core::{EstimatorParams, Model};
use crate::scene::Scene;
use serde_json::{json, Map, Value};
use std::fmt::Write;

const RENDERER_TITLES: [&str; 2] = [
    "(a) light field through the plane at w_opt",
    "(b) depth-aided warping",
];
const SETTING_TITLES: [&str; 2] = [
    "each method at its own spacing",
    "equal number of captures (each method's spacing scaled to the occlusion-aware count)",
];

pub(super) fn num(x: f64) -> Value {
    if x.is_finite() {
        json!(x)
    } else {
        Value::Null
    }
}

/// scene → method → setting → renderer → {captures, psnr_db, ssim}.
pub fn results_json(results: &[SceneResult]) -> Value {
    let mut top = Map::new();
    for r in results {
        let mut scene = Map::new();
        for (m, model) in METHODS.iter().enumerate() {
            let mut method = Map::new();
            for (s, setting) in SETTINGS.iter().enumerate() {
                let run = &r.runs[m][s];
                let mut set = Map::new();
                for (k, renderer) in RENDERERS.iter().enumerate() {
                    set.insert(
                        renderer.to_string(),
                        json!({
                            "captures": run.captures.len(),
                            "psnr_db": num(run.mean_psnr_db[k]),
                            "ssim": num(run.mean_ssim[k]),
                        }),
                    );
                }
                method.insert(setting.to_string(), Value::Object(set));
            }
            scene.insert(model.as_str().to_string(), Value::Object(method));
        }
        if let Value::Object(extra) = super::tables::scene_json(r) {
            scene.extend(extra);
        }
        top.insert(r.name.clone(), Value::Object(scene));
    }
    top.insert("segments".into(), super::tables::segments_json(results));
    top.insert(
        "targets".into(),
        super::tables::targets_json(&super::truth::DEFAULT_TARGETS),
    );
    Value::Object(top)
}

fn table(
    results: &[SceneResult],
    value: impl Fn(&SceneResult, usize) -> f64,
    fmt: impl Fn(f64) -> String,
) -> String {
    let mut s = String::from("| method |");
    for r in results {
        let _ = write!(s, " {} |", r.name);
    }
    s.push_str(" mean |\n|---|");
    for _ in 0..=results.len() {
        s.push_str("---:|");
    }
    s.push('\n');
    for (m, model) in METHODS.iter().enumerate() {
        let _ = write!(s, "| {} |", model.as_str());
        let vals: Vec<f64> = results.iter().map(|r| value(r, m)).collect();
        for v in &vals {
            let _ = write!(s, " {} |", fmt(*v));
        }
        let _ = writeln!(
            s,
            " {} |",
            fmt(vals.iter().sum::<f64>() / vals.len() as f64)
        );
    }
    s
}

fn mean_over(results: &[SceneResult], f: impl Fn(&SceneResult) -> f64) -> f64 {
    results.iter().map(f).sum::<f64>() / results.len().max(1) as f64
}

fn opt_m(x: Option<f64>) -> String {
    match x {
        Some(v) if v.is_finite() => format!("{v:.3}"),
        _ => "unbounded".into(),
    }
}

pub fn markdown(
    results: &[SceneResult],
    quick: bool,
    total_s: f64,
    decimation: Option<&str>,
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# alfd eval{}\n", if quick { " --quick" } else { "" });
    let _ = writeln!(
        s,
        "PSNR (dB, peak 1) and SSIM (Wang et al. 2004, 11×11 Gaussian σ = 1.5, K1 = 0.01, K2 = 0.03) on luminance (Rec. 601 luma), mean over every in-between view (captured views are exact and left out). Method: `docs/eval.md`.\n"
    );
    let _ = writeln!(
        s,
        "| scene | resolution | dense views | view step (m) | time (s) | of which rendering / sweeps / method runs / data volume / quality at equal captures (s) |"
    );
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|");
    for r in results {
        let _ = writeln!(
            s,
            "| {} | {}×{} ×{}² supersampled | {} | {:.3} | {:.1} | {:.1} / {:.1} / {:.1} / {:.1} / {:.1} |",
            r.name,
            r.res.width,
            r.res.height,
            r.res.supersample,
            r.views,
            r.res.view_step_m,
            r.elapsed_s,
            r.render_s,
            r.stage_s[0],
            r.stage_s[1],
            r.stage_s[2],
            r.stage_s[3]
        );
    }
    let _ = writeln!(
        s,
        "\nTotal run time: {total_s:.1} s on {} threads.\n",
        rayon::current_num_threads()
    );

    s.push_str(&super::tables::markdown(results));

    for (si, st) in SETTING_TITLES.iter().enumerate() {
        let _ = writeln!(s, "## Setting: {st}\n");
        let _ = writeln!(s, "Captures:\n");
        s.push_str(&table(
            results,
            |r, m| r.runs[m][si].captures.len() as f64,
            |v| format!("{v:.1}"),
        ));
        if si == 1 {
            let _ = writeln!(s, "\nSpacing scale found by the bisection:\n");
            s.push_str(&table(
                results,
                |r, m| r.runs[m][si].scale,
                |v| format!("{v:.3}"),
            ));
        }
        for (k, rt) in RENDERER_TITLES.iter().enumerate() {
            let _ = writeln!(s, "\n### Renderer {rt}: PSNR (dB)\n");
            s.push_str(&table(
                results,
                |r, m| r.runs[m][si].mean_psnr_db[k],
                |v| format!("{v:.2}"),
            ));
            let _ = writeln!(s, "\n### Renderer {rt}: SSIM\n");
            s.push_str(&table(
                results,
                |r, m| r.runs[m][si].mean_ssim[k],
                |v| format!("{v:.4}"),
            ));
        }
        s.push('\n');
    }

    let _ = writeln!(s, "## The claim at equal captures (mean over the scenes)\n");
    let _ = writeln!(s, "Paper: occlusion-aware ≥ MMDS + 0.85 dB / + 0.028 SSIM and ≥ SSPA + 1.15 dB / + 0.035 SSIM.\n");
    let _ = writeln!(s, "| renderer | occl − MMDS (dB) | occl − SSPA (dB) | occl − MMDS (SSIM) | occl − SSPA (SSIM) | holds? |");
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---|");
    for (k, rn) in RENDERERS.iter().enumerate() {
        let d = |m: usize, f: &dyn Fn(&super::MethodRun) -> f64| {
            mean_over(results, |r| f(&r.runs[0][1]) - f(&r.runs[m][1]))
        };
        let p = |run: &super::MethodRun| run.mean_psnr_db[k];
        let q = |run: &super::MethodRun| run.mean_ssim[k];
        let (pm, ps, qm, qs) = (d(1, &p), d(2, &p), d(1, &q), d(2, &q));
        let holds = pm >= 0.85 && ps >= 1.15 && qm >= 0.028 && qs >= 0.035;
        let _ = writeln!(
            s,
            "| {rn} | {pm:+.2} | {ps:+.2} | {qm:+.4} | {qs:+.4} | {} |",
            if holds { "yes" } else { "no" }
        );
    }

    let _ = writeln!(
        s,
        "\n## Empirical permissible spacing against each model's prediction\n"
    );
    let _ = writeln!(s, "Empirical: the largest swept spacing whose mean PSNR over the segment's in-between views (uniform captures) stays within the tolerance of a reference. Issue's reference: the finest swept spacing (2 view steps), tolerances 0.5 dB / 1 dB / 2 dB. Dense reference: the largest swept spacing with at most 1 px of disparity per step at the segment's median nearest depth (a densely sampled light field), tolerance 0.5 dB; column `dense` gives that 1 px spacing. `≥` where the sweep never left the tolerance. Predictions: median over the segment's views of each model's permissible spacing (before the config limits). Ratios: prediction / empirical (a) against the finest reference at 0.5 dB and against the dense reference.\n");
    let _ = writeln!(s, "| scene | segment x (m) | empirical (a) 0.5 / 1 / 2 dB; dense | empirical (b) 0.5 / 1 / 2 dB; dense | dense (m) | occlusion | MMDS | SSPA | occl / emp (a) | MMDS / emp (a) | SSPA / emp (a) |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in results {
        for seg in &r.segments {
            let e = |k: usize| {
                (0..4)
                    .map(|t| {
                        format!(
                            "{}{:.2}",
                            if seg.at_least[t][k] { "≥ " } else { "" },
                            seg.empirical_m[t][k]
                        )
                    })
                    .collect::<Vec<_>>()
                    .join(" / ")
                    .replacen(" / ", "; ", 3)
                    .replacen("; ", " / ", 2)
            };
            let ratio = |m: usize| match seg.predicted_m[m] {
                Some(p) if p.is_finite() => format!(
                    "{:.2}, {:.2}",
                    p / seg.empirical_m[0][0],
                    p / seg.empirical_m[super::DENSE_CRITERION][0]
                ),
                _ => "–".into(),
            };
            let _ = writeln!(
                s,
                "| {} | {:.1} – {:.1} | {} | {} | {:.3} | {} | {} | {} | {} | {} | {} |",
                r.name,
                seg.x0_m,
                seg.x1_m,
                e(0),
                e(1),
                seg.dense_m,
                opt_m(seg.predicted_m[0]),
                opt_m(seg.predicted_m[1]),
                opt_m(seg.predicted_m[2]),
                ratio(0),
                ratio(1),
                ratio(2)
            );
        }
    }

    let _ = writeln!(s, "\nThe sweeps (mean PSNR of the segment's in-between views, renderer a / b, at each spacing in metres):\n");
    for r in results {
        for seg in &r.segments {
            let _ = write!(s, "- {} {:.1} – {:.1} m:", r.name, seg.x0_m, seg.x1_m);
            for p in &seg.sweep {
                let _ = write!(
                    s,
                    " {:.2}: {:.2} / {:.2};",
                    p.spacing_m, p.psnr_db[0], p.psnr_db[1]
                );
            }
            s.push('\n');
        }
    }

    let _ = writeln!(
        s,
        "\n## Data volume against fixed-distance triggering (by PSNR)\n"
    );
    let _ = writeln!(s, "Worst-case PSNR: the lowest segment mean, renderer (a), each method at its own spacing. Fixed at equal worst case: the largest uniform spacing of the sweeps whose worst segment still reaches that PSNR, and the captures fixed-distance triggering needs at it over the line. Safe spacing: the worst segment's target spacing by the truth, the fixed method of the tables.\n");
    let _ = writeln!(s, "| scene | safe spacing (m) | captures at it | method | captures | worst-case PSNR (dB) | fixed spacing at equal worst case (m) | fixed captures | method / fixed |");
    let _ = writeln!(s, "|---|---:|---:|---|---:|---:|---:|---:|---:|");
    for r in results {
        for (model, runs) in METHODS.iter().zip(&r.runs).take(3) {
            let run = &runs[0];
            let worst = run
                .segment_psnr_db
                .iter()
                .map(|p| p[0])
                .fold(f64::INFINITY, f64::min);
            let fixed = super::fixed_at_equal_worst_case(r, 0, worst);
            let _ = writeln!(
                s,
                "| {} | {:.2} | {} | {} | {} | {:.2} | {} | {} | {} |",
                r.name,
                r.safe_spacing_m,
                r.runs[3][0].captures.len(),
                model.as_str(),
                run.captures.len(),
                worst,
                fixed.map_or("< finest".into(), |f| format!("{:.2}", f.0)),
                fixed.map_or("–".into(), |f| f.1.to_string()),
                fixed.map_or("–".into(), |f| format!(
                    "{:.2}",
                    run.captures.len() as f64 / f.1 as f64
                )),
            );
        }
    }

    let _ = writeln!(s, "\n## Calibration of O_max\n");
    let _ = writeln!(s, "Mean |ln(prediction / empirical)| of `min(MMDS, O_max/ρ)` (median over each segment's views) against the empirical spacing of renderer (a) at each tolerance; fit on {:?}, held out: the others (number of segments in brackets; segments with only a lower bound are left out).\n", super::CALIBRATION_FIT);
    let tables: Vec<_> = (0..4)
        .map(|t| calibrate_occlusion_max(results, 0, t))
        .collect();
    let _ = writeln!(s, "| O_max | fit 0.5 dB | held out 0.5 dB | fit 1 dB | held out 1 dB | fit 2 dB | held out 2 dB | fit dense 0.5 dB | held out dense 0.5 dB |");
    let _ = writeln!(s, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (row, o) in tables[0].iter().map(|r| r.0).enumerate() {
        let _ = write!(s, "| {o:.4} |");
        for t in &tables {
            let (_, f, nf, h, nh) = t[row];
            let _ = write!(s, " {f:.3} ({nf}) | {h:.3} ({nh}) |");
        }
        s.push('\n');
    }
    for (t, tol) in super::TOLERANCES_DB.iter().enumerate() {
        if let Some(b) = tables[t]
            .iter()
            .filter(|r| r.1.is_finite())
            .min_by(|a, b| a.1.total_cmp(&b.1))
        {
            let _ = writeln!(
                s,
                "\nBest fit at {tol} dB{}: O_max = {:.4} (fit error {:.3}, held out {:.3}).",
                if t == super::DENSE_CRITERION {
                    " from the dense reference"
                } else {
                    ""
                },
                b.0,
                b.1,
                b.3
            );
        }
    }
    s.push('\n');

    if let Some(d) = decimation {
        let _ = writeln!(
            s,
            "## Error against run time on rendered depth (mid-track view of each scene)\n"
        );
        s.push_str(d);
    }
    s
}

/// The core's decimation table on the middle view of each scene (Z16 as the
/// evaluation's sensor gives it).
pub fn decimation_table(scenes: &[Scene], quick: bool) -> String {
    let frames: Vec<crate::tradeoff::Frame> = scenes
        .iter()
        .map(|sc| {
            let res = super::Resolution::of(sc, quick);
            let x = 0.5 * (sc.survey.start_x_m + sc.survey.end_x_m);
            let cam = crate::render::survey_camera(sc, x, res.width, res.height);
            let frame =
                crate::render::render(sc, &cam, &crate::render::RenderOptions { supersample: 1 });
            crate::tradeoff::Frame {
                name: sc.name.clone(),
                image: frame.z16(&super::eval_sensor()),
                intrinsics: cam.intrinsics,
                pitch_rad: sc.survey.pitch_rad,
            }
        })
        .collect();
    let rows = crate::tradeoff::measure(
        &frames,
        &EstimatorParams::default(),
        &[Model::Mmds, Model::Sspa, Model::Occlusion],
        &crate::core::params::DECIMATION_LEVELS,
        if quick { 3 } else { 9 },
    );
    crate::tradeoff::markdown(&frames, &rows)
}
