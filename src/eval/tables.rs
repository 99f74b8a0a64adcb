//! The truth's tables of `alfd eval` (issue 12): per-segment empirical
//! spacings against each model, what each target level costs in quality, the
//! data volume at a guarantee, quality per pixel class and at equal captures;
//! and their `results.json` keys (`segments`, `targets`, per scene `guarantee`).

use super::report::num;
use super::truth::{Targets, CLASS_NAMES, DEFAULT_TARGETS};
use super::{
    SceneResult, Segment, SegmentTruth, SweepPoint, CALIBRATION_FIT, METHODS, PARALLAX_LEVELS_PX,
    RENDERERS, UNSEEN_LEVELS,
};
use serde_json::{json, Map, Value};
use std::fmt::Write;

fn onum(x: Option<f64>) -> Value {
    x.map_or(Value::Null, num)
}

fn f(x: Option<f64>, digits: usize) -> String {
    match x {
        Some(v) if v.is_finite() => format!("{v:.digits$}"),
        Some(_) => "∞".into(),
        None => "–".into(),
    }
}

/// `≥ x` where the sweep ended before the criterion failed, `< finest` where
/// even the finest spacing failed.
fn bound(x: Option<f64>, at_least: bool) -> String {
    match x {
        None => "< finest".into(),
        Some(v) if at_least => format!("≥ {v:.2}"),
        Some(v) => format!("{v:.2}"),
    }
}

/// Which target sets the segment's empirical spacing.
pub fn binding(seg: &Segment) -> &'static str {
    let t = &seg.truth;
    let cands = [
        ("parallax", t.parallax_m),
        ("unseen", t.unseen_m),
        ("views_per_point", t.views_per_point_m),
    ];
    cands
        .iter()
        .filter_map(|(n, v)| v.map(|v| (*n, v)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or("none", |(n, _)| n)
}

fn held(name: &str) -> &'static str {
    if CALIBRATION_FIT.contains(&name) {
        "in"
    } else {
        "out"
    }
}

/// The sweep point with the largest spacing before `ok` first fails.
fn last_meeting(seg: &Segment, ok: impl Fn(&SweepPoint) -> bool) -> Option<&SweepPoint> {
    seg.sweep.iter().take_while(|p| ok(p)).last()
}

pub fn targets_json(t: &Targets) -> Value {
    json!({
        "profile": "lightfield",
        "parallax_px": t.parallax_px,
        "unseen_fraction_max": t.unseen_fraction_max,
        "views_per_point_min": t.views_per_point_min,
    })
}

/// `ln(predicted / empirical)` of a segment's target spacing, where both are bounded.
fn ln_error(t: &SegmentTruth, predicted_m: Option<f64>) -> Option<f64> {
    match (predicted_m, t.target_m) {
        (Some(p), Some(e)) if p.is_finite() && !t.target_at_least => Some((p / e).ln()),
        _ => None,
    }
}

/// `results.json`'s `segments` (DESIGN §4).
pub fn segments_json(results: &[SceneResult]) -> Value {
    let mut out = Vec::new();
    for r in results {
        for seg in &r.segments {
            let t = &seg.truth;
            let mut pred = Map::new();
            for (m, model) in METHODS.iter().enumerate() {
                pred.insert(model.as_str().into(), onum(seg.predicted_m[m]));
            }
            pred.insert("visibility".into(), onum(t.visibility_predicted_m));
            pred.insert("visibility_tightest".into(), onum(t.visibility_tightest_m));
            let ln_err = |p: Option<f64>| ln_error(t, p).map_or(Value::Null, num);
            out.push(json!({
                "scene": r.name,
                "held": held(&r.name),
                "from_m": seg.x0_m,
                "to_m": seg.x1_m,
                "binds": binding(seg),
                "empirical_m": {
                    "target": onum(t.target_m),
                    "target_at_least": t.target_at_least,
                    "parallax": onum(t.parallax_m),
                    "parallax_at_least": t.parallax_at_least,
                    "unseen": onum(t.unseen_m),
                    "unseen_at_least": t.unseen_at_least,
                    "views_per_point": onum(t.views_per_point_m),
                    "psnr_0.5db": {"lightfield": num(seg.empirical_m[0][0]), "warp": num(seg.empirical_m[0][1])},
                    "psnr_1db": {"lightfield": num(seg.empirical_m[1][0]), "warp": num(seg.empirical_m[1][1])},
                    "psnr_2db": {"lightfield": num(seg.empirical_m[2][0]), "warp": num(seg.empirical_m[2][1])},
                },
                "predicted_m": Value::Object(pred),
                "ln_error": {"occlusion": ln_err(seg.predicted_m[0]), "mmds": ln_err(seg.predicted_m[1]), "sspa": ln_err(seg.predicted_m[2]), "visibility": ln_err(t.visibility_predicted_m), "visibility_tightest": ln_err(t.visibility_tightest_m)},
                "unseen_fraction": {"predicted": onum(t.unseen_predicted), "predicted_visibility": onum(t.unseen_visibility_predicted), "truth": onum(t.unseen_truth)},
                "parallax_px": {"predicted": onum(t.parallax_predicted_px), "open_loop": onum(t.parallax_open_px), "closed_loop": onum(t.parallax_closed_px), "truth": onum(t.parallax_truth_px)},
                "unseen_fraction_quality": {"open_loop": onum(t.unseen_open), "closed_loop": onum(t.unseen_closed), "truth": onum(t.unseen_truth)},
                "unseen_fraction_where_exceeded": t.unseen_exceeded.map(|u| json!({"spacing_m": u.spacing_m, "open_loop": onum(u.open), "closed_loop": onum(u.closed), "truth": u.truth})),
                "visibility_interval_m": {"min": onum(t.interval_min_m), "p01": onum(t.interval_p01_m), "points": t.points},
                "sweep": seg.sweep.iter().map(|p| json!({
                    "spacing_m": p.spacing_m,
                    "unseen_fraction": {"median": num(p.geo.unseen_median), "worst": num(p.geo.unseen_worst)},
                    "parallax_px": {"median": onum(p.geo.parallax_median_px), "worst": onum(p.geo.parallax_worst_px)},
                    "out_of_both_fraction": {"median": num(p.geo.out_of_both_median)},
                    "scored_views": p.scored,
                    "psnr_db": {"lightfield": num(p.psnr_db[0]), "warp": num(p.psnr_db[1])},
                    "ssim": {"lightfield": num(p.ssim[0]), "warp": num(p.ssim[1])},
                    "class_psnr_db": class_json(&p.classes.psnr_db),
                    "class_fraction": {"both": num(p.classes.fraction[0]), "one": num(p.classes.fraction[1]), "neither": num(p.classes.fraction[2])},
                })).collect::<Vec<_>>(),
            }));
        }
    }
    Value::Array(out)
}

fn class_json(v: &[[f64; 3]; 2]) -> Value {
    let mut m = Map::new();
    for (r, rn) in RENDERERS.iter().enumerate() {
        let mut c = Map::new();
        for (k, cn) in CLASS_NAMES.iter().enumerate() {
            c.insert((*cn).into(), num(v[r][k]));
        }
        m.insert((*rn).into(), Value::Object(c));
    }
    Value::Object(m)
}

/// Per scene: the guarantee, and each method's per-class quality and
/// per-segment truth at its own spacing and at equal captures.
pub fn scene_json(r: &SceneResult) -> Value {
    let g = &r.guarantee;
    let methods: Vec<Value> = g
        .methods
        .iter()
        .map(|run| {
            json!({
                "method": run.method,
                "scale": num(run.scale),
                "captures": run.captures,
                "unseen_worst": num(run.geo.unseen_worst),
                "parallax_worst_px": onum(run.geo.parallax_worst_px),
                "min_views": run.min_views,
                "meets": run.meets,
                "interval_bound": {
                    "scale": num(run.interval_scale),
                    "captures": run.interval_captures,
                },
            })
        })
        .collect();
    let runs: Vec<Value> = METHODS
        .iter()
        .enumerate()
        .map(|(m, model)| {
            let setting = |s: usize| {
                let run = &r.runs[m][s];
                json!({
                    "captures": run.captures.len(),
                    "class_psnr_db": class_json(&run.classes.psnr_db),
                    "class_ssim": class_json(&run.classes.ssim),
                    "class_fraction": {"both": num(run.classes.fraction[0]), "one": num(run.classes.fraction[1]), "neither": num(run.classes.fraction[2])},
                    "segments": run.segment_geo.iter().zip(&run.segment_psnr_db).zip(&run.segment_ssim).map(|((g, p), q)| json!({
                        "unseen_worst": num(g.unseen_worst),
                        "parallax_worst_px": onum(g.parallax_worst_px),
                        "psnr_db": {"lightfield": num(p[0]), "warp": num(p[1])},
                        "ssim": {"lightfield": num(q[0]), "warp": num(q[1])},
                    })).collect::<Vec<_>>(),
                })
            };
            json!({"method": model.as_str(), "own": setting(0), "equal": setting(1)})
        })
        .collect();
    let colmap: Map<String, Value> = r
        .colmap
        .iter()
        .map(|(m, v)| {
            let v = match v {
                Ok(j) => {
                    let mut j = j.clone();
                    if let Value::Object(o) = &mut j {
                        o.remove("per_image");
                    }
                    j
                }
                Err(e) => json!({ "error": e }),
            };
            (m.clone(), v)
        })
        .collect();
    let quality_equal: Vec<Value> = r
        .quality_equal
        .iter()
        .map(|e| {
            json!({
                "method": e.method,
                "scale": num(e.run.scale),
                "captures": e.run.captures.len(),
                "min_views": e.min_views,
                "segments": e.run.segment_geo.iter().zip(&e.run.segment_psnr_db).zip(&e.run.segment_ssim).map(|((g, p), q)| json!({
                    "unseen_worst": num(g.unseen_worst),
                    "parallax_worst_px": onum(g.parallax_worst_px),
                    "psnr_db": {"lightfield": num(p[0]), "warp": num(p[1])},
                    "ssim": {"lightfield": num(q[0]), "warp": num(q[1])},
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    let flown: Vec<Value> = r
        .flown
        .iter()
        .map(|run| {
            json!({
                "mode": run.mode,
                "captures": run.captures.len(),
                "unseen_worst": num(run.geo.unseen_worst),
                "parallax_worst_px": onum(run.geo.parallax_worst_px),
                "min_views": run.min_views,
                "meets": run.meets,
                "segment_captures": run.segment_captures,
                "closed_loop_captures_by_bound": run.closed.as_ref().map(|c| c.by_bound.iter().map(|(b, k)| (b.to_string(), json!(k))).collect::<Map<String, Value>>()),
            })
        })
        .collect();
    json!({
        "quality_as_flown": flown,
        "quality_at_equal_captures": quality_equal,
        "colmap": Value::Object(colmap),
        "guarantee": {
            "fixed_spacing_m": onum(g.fixed_spacing_m),
            "fixed_captures": g.fixed_captures,
            "oracle_captures": g.oracle_captures,
            "methods": methods,
        },
        "truth_by_method": runs,
    })
}

/// The truth's sections of `report.md`.
pub fn markdown(results: &[SceneResult]) -> String {
    let t = DEFAULT_TARGETS;
    let mut s = String::new();
    let _ = writeln!(s, "## The truth: what each neighbouring capture sees\n");
    let _ = writeln!(s, "Default targets (DESIGN §1, `lightfield`): parallax ≤ {} px per step, unseen fraction ≤ {}, views per point ≥ {}. For every in-between view, each surface pixel is classified from the true depth as seen by both neighbouring captures, by one, by neither (out of both frusta apart); the parallax span is the disparity range between the two captures (0.5–99.5 percentiles) over the pixels both see. Views per point: each sampled surface point's interval of camera positions along the line from which it is visible (exact ray casting); a uniform spacing keeps every point in ≥ k captures whatever the phase iff it is ≤ the shortest interval / k. Held in (fit): {:?}; the others held out.\n", t.parallax_px, t.unseen_fraction_max, t.views_per_point_min, CALIBRATION_FIT);

    let _ = writeln!(
        s,
        "### Empirical permissible spacing per segment, and each model's prediction\n"
    );
    let _ = writeln!(s, "Empirical (m): the largest uniform spacing of the sweep (neighbours ≤ 1.25× apart) meeting each target by the truth, over every in-between view of the segment; `target` meets all three. `≥`: the sweep reached the segment's length first. Predictions: median over the segment's views of each model's permissible spacing; for the quality model also the tightest view's, which is what the trigger flies (it applies the tightest spacing seen since the last capture). At the target spacing: parallax (px) predicted by the MMDS formula from live depth against the worst true span; unseen fraction predicted by the occlusion model `ρ·b` against the worst true fraction.\n");
    let _ = writeln!(s, "| scene | held | segment x (m) | target | parallax | unseen | views/pt (shortest interval) | binds | occlusion | MMDS | SSPA | quality: median / tightest frame | parallax at target: pred / truth | unseen at target: ρ·b / quality / truth |");
    let _ = writeln!(
        s,
        "|---|---|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|"
    );
    for r in results {
        for seg in &r.segments {
            let tr = &seg.truth;
            let _ = writeln!(
                s,
                "| {} | {} | {:.1} – {:.1} | {} | {} | {} | {} ({}) | {} | {} | {} | {} | {} / {} | {} / {} | {} / {} / {} |",
                r.name,
                held(&r.name),
                seg.x0_m,
                seg.x1_m,
                bound(tr.target_m, tr.target_at_least),
                bound(tr.parallax_m, tr.parallax_at_least),
                bound(tr.unseen_m, tr.unseen_at_least),
                f(tr.views_per_point_m, 2),
                f(tr.interval_min_m, 2),
                binding(seg),
                f(seg.predicted_m[0], 3),
                f(seg.predicted_m[1], 3),
                f(seg.predicted_m[2], 3),
                f(tr.visibility_predicted_m, 3),
                f(tr.visibility_tightest_m, 3),
                f(tr.parallax_predicted_px, 2),
                f(tr.parallax_truth_px, 2),
                f(tr.unseen_predicted, 4),
                f(tr.unseen_visibility_predicted, 4),
                f(tr.unseen_truth, 4),
            );
        }
    }

    let _ = writeln!(s, "\nAccuracy of each model against the target spacing: |ln(prediction / empirical)| over segments with a bounded empirical value, mean / median / worst (number of segments). `visibility` is the daemon's default, the quality model (issue 13) with these targets, open loop from one frame: the largest spacing keeping the disparity span ≤ the parallax target (each pixel's own gain off nadir), the predicted unseen fraction ≤ target and every point of the middle half in ≥ k captures; the median view's (as the other models), and the tightest view's: the trigger applies the tightest spacing seen since the last capture, and the empirical spacing is the segment's worst in-between view's.\n");
    let _ = writeln!(s, "| model | held in | held out |");
    let _ = writeln!(s, "|---|---:|---:|");
    /// A model's prediction for a segment.
    type Predicted = fn(&Segment) -> Option<f64>;
    let models: [(&str, Predicted); 5] = [
        ("occlusion", |seg| seg.predicted_m[0]),
        ("mmds", |seg| seg.predicted_m[1]),
        ("sspa", |seg| seg.predicted_m[2]),
        ("visibility", |seg| seg.truth.visibility_predicted_m),
        ("visibility, tightest frame", |seg| {
            seg.truth.visibility_tightest_m
        }),
    ];
    for (model, predicted) in models {
        let acc = |inside: bool| {
            let mut v: Vec<f64> = Vec::new();
            for r in results
                .iter()
                .filter(|r| CALIBRATION_FIT.contains(&r.name.as_str()) == inside)
            {
                for seg in &r.segments {
                    if let Some(e) = ln_error(&seg.truth, predicted(seg)) {
                        v.push(e.abs());
                    }
                }
            }
            if v.is_empty() {
                "–".to_string()
            } else {
                v.sort_by(f64::total_cmp);
                format!(
                    "{:.3} / {:.3} / {:.3} ({})",
                    v.iter().sum::<f64>() / v.len() as f64,
                    v[v.len() / 2],
                    v[v.len() - 1],
                    v.len()
                )
            }
        };
        let _ = writeln!(s, "| {} | {} | {} |", model, acc(true), acc(false));
    }

    let _ = write!(s, "{}", geometry_accuracy(results));

    let _ = writeln!(s, "\n### The sweeps' geometry\n");
    let _ = writeln!(s, "Per segment and spacing (m): worst unseen fraction / worst parallax span (px) over the segment's in-between views.\n");
    for r in results {
        for seg in &r.segments {
            let _ = write!(s, "- {} {:.1} – {:.1} m:", r.name, seg.x0_m, seg.x1_m);
            for p in &seg.sweep {
                let _ = write!(
                    s,
                    " {:.2}: {:.4} / {};",
                    p.spacing_m,
                    p.geo.unseen_worst,
                    f(p.geo.parallax_worst_px, 1)
                );
            }
            s.push('\n');
        }
    }

    let _ = writeln!(
        s,
        "\n### What a target level costs: quality at the largest spacing meeting it\n"
    );
    let _ = writeln!(s, "Per scene: the mean over its segments of the quality (PSNR dB / SSIM of the scored in-between views) at the largest swept spacing whose worst view meets the level; spread: min – max over scenes. Renderer (a) light field through the plane at w_opt, (b) depth-aided warping.\n");
    for (title, levels, ok) in [
        (
            "parallax span (px)",
            &PARALLAX_LEVELS_PX[..],
            (|p: &SweepPoint, l: f64| p.geo.parallax_worst_px.is_none_or(|x| x <= l))
                as fn(&SweepPoint, f64) -> bool,
        ),
        (
            "unseen fraction",
            &UNSEEN_LEVELS[..],
            (|p: &SweepPoint, l: f64| p.geo.unseen_worst <= l) as fn(&SweepPoint, f64) -> bool,
        ),
    ] {
        for (ri, rn) in ["(a)", "(b)"].iter().enumerate() {
            let _ = writeln!(s, "\n#### {title}, renderer {rn}\n");
            let _ = write!(s, "| level |");
            for r in results {
                let _ = write!(s, " {} |", r.name);
            }
            let _ = writeln!(s, " spread PSNR | spread SSIM |");
            let _ = write!(s, "|---:|");
            for _ in 0..results.len() + 2 {
                s.push_str("---:|");
            }
            s.push('\n');
            for &l in levels {
                let _ = write!(s, "| {l} |");
                let mut ps = Vec::new();
                let mut qs = Vec::new();
                for r in results {
                    let pts: Vec<&SweepPoint> = r
                        .segments
                        .iter()
                        .filter_map(|seg| last_meeting(seg, |p| ok(p, l)))
                        .collect();
                    if pts.is_empty() {
                        let _ = write!(s, " – |");
                        continue;
                    }
                    let p = pts.iter().map(|p| p.psnr_db[ri]).sum::<f64>() / pts.len() as f64;
                    let q = pts.iter().map(|p| p.ssim[ri]).sum::<f64>() / pts.len() as f64;
                    ps.push(p);
                    qs.push(q);
                    let _ = write!(s, " {p:.2} / {q:.4} |");
                }
                let spread = |v: &[f64], d: usize| {
                    if v.is_empty() {
                        "–".into()
                    } else {
                        format!(
                            "{:.d$} – {:.d$}",
                            v.iter().copied().fold(f64::INFINITY, f64::min),
                            v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                        )
                    }
                };
                let _ = writeln!(s, " {} | {} |", spread(&ps, 2), spread(&qs, 4));
            }
        }
    }

    let _ = writeln!(
        s,
        "\n### Quality by pixel class, each method at its own spacing\n"
    );
    let _ = writeln!(s, "Fraction of in-frustum surface pixels in each class (both / one / neither), and PSNR (dB) of each class's pixels pooled over the scene's in-between views, renderer (a) then (b); `–` where a class is empty.\n");
    let _ = writeln!(s, "| scene | method | fraction both / one / neither | (a) both / one / neither | (b) both / one / neither | SSIM (b) both / one / neither |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|");
    for r in results {
        for (m, model) in METHODS.iter().enumerate() {
            let c = &r.runs[m][0].classes;
            let tri = |v: [f64; 3], d: usize| {
                v.map(|x| {
                    if x.is_finite() {
                        format!("{x:.d$}")
                    } else {
                        "–".into()
                    }
                })
                .join(" / ")
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} |",
                r.name,
                model.as_str(),
                tri(c.fraction, 4),
                tri(c.psnr_db[0], 2),
                tri(c.psnr_db[1], 2),
                tri(c.ssim[1], 4)
            );
        }
    }

    let _ = writeln!(
        s,
        "\n### Each method against the targets at its own spacing\n"
    );
    let _ = writeln!(s, "Worst segment by the truth: worst unseen fraction and worst parallax span (px) over its in-between views.\n");
    let _ = writeln!(s, "| scene | method | captures | worst unseen | worst parallax (px) | meets parallax and unseen |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|---|");
    for r in results {
        for (m, model) in METHODS.iter().enumerate() {
            let run = &r.runs[m][0];
            let worst_u = run
                .segment_geo
                .iter()
                .map(|g| g.unseen_worst)
                .fold(0.0, f64::max);
            let worst_p = run
                .segment_geo
                .iter()
                .filter_map(|g| g.parallax_worst_px)
                .reduce(f64::max);
            let meets = run.segment_geo.iter().all(|g| g.meets(&t));
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.4} | {} | {} |",
                r.name,
                model.as_str(),
                run.captures.len(),
                worst_u,
                f(worst_p, 2),
                if meets { "yes" } else { "no" }
            );
        }
    }

    let _ = writeln!(s, "\n### Data volume at the targets\n");
    let _ = writeln!(s, "Each method's spacing scaled by one constant, the largest whose plan meets every target by the truth (worst unseen fraction and parallax over all its in-between views, fewest captures seeing a sampled point): searched from the interval bound to 0.3 % on the sweeps' nine views per interval, then confirmed on every in-between view, stepping down 1.2 % at a time until that holds; the plan at scale 1 (as flown) instead when it meets the targets with fewer captures. Interval bound: the largest scale keeping every capture interval within the target spacing of each segment it overlaps, a sufficient rule that an adaptive plan need not keep. Fixed: fixed-distance triggering at the worst segment's target spacing; oracle: each segment at its own.\n");
    let _ = writeln!(s, "| scene | fixed spacing (m) | fixed captures | oracle captures | method | scale | captures | / fixed | / oracle | worst unseen | worst parallax (px) | fewest views | meets | interval bound: scale / captures / oracle |");
    let _ = writeln!(
        s,
        "|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---|---:|"
    );
    for r in results {
        let g = &r.guarantee;
        if g.methods.is_empty() {
            let _ = writeln!(
                s,
                "| {} | – | – | – | (a segment meets no swept spacing) | | | | | | | | |",
                r.name
            );
            continue;
        }
        for run in &g.methods {
            let ratio = |d: Option<usize>| {
                d.map_or("–".into(), |d| {
                    format!("{:.2}", run.captures as f64 / d as f64)
                })
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {:.3} | {} | {} | {} | {:.4} | {} | {} | {} | {:.3} / {} / {} |",
                r.name,
                f(g.fixed_spacing_m, 2),
                g.fixed_captures.map_or("–".into(), |c| c.to_string()),
                g.oracle_captures.map_or("–".into(), |c| c.to_string()),
                run.method,
                run.scale,
                run.captures,
                ratio(g.fixed_captures),
                ratio(g.oracle_captures),
                run.geo.unseen_worst,
                f(run.geo.parallax_worst_px, 2),
                run.min_views.map_or("–".into(), |v| v.to_string()),
                if run.meets { "yes" } else { "no" },
                run.interval_scale,
                run.interval_captures,
                g.oracle_captures.map_or("–".into(), |d| format!(
                    "{:.2}",
                    run.interval_captures as f64 / d as f64
                )),
            );
        }
    }

    let _ = writeln!(
        s,
        "\n### The quality model as flown: open loop, and with the closed loop\n"
    );
    let _ = writeln!(s, "The quality model at scale 1 (what the daemon flies, no search), open loop, and with `[trigger] closed_loop = true`: each view's kept depth (about 4800 samples) measured against the last capture, the tighter of the two spacings. Judged by the truth on every in-between view; fewest views as the data-volume table. Closed-loop captures: how many the closed loop set (it was the tighter), by bound.\n");
    let _ = writeln!(s, "| scene | mode | captures | / fixed | / oracle | worst unseen | worst parallax (px) | fewest views | meets | closed-loop captures by bound |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|---|---|");
    for r in results {
        let g = &r.guarantee;
        for run in &r.flown {
            let n = run.captures.len();
            let ratio = |d: Option<usize>| {
                d.map_or("–".into(), |d| format!("{:.2}", n as f64 / d as f64))
            };
            let bounds = match &run.closed {
                Some(c) if c.by_bound.is_empty() => "none".to_string(),
                Some(c) => c
                    .by_bound
                    .iter()
                    .map(|(b, k)| format!("{b} {k}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                None => "–".to_string(),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {:.4} | {} | {} | {} | {} |",
                r.name,
                run.mode,
                n,
                ratio(g.fixed_captures),
                ratio(g.oracle_captures),
                run.geo.unseen_worst,
                f(run.geo.parallax_worst_px, 2),
                run.min_views.map_or("–".into(), |v| v.to_string()),
                if run.meets { "yes" } else { "no" },
                bounds,
            );
        }
    }
    let _ = writeln!(s, "\nPer segment, captures inside it as flown, open / closed loop, and the segment's target spacing by the truth (m):\n");
    for r in results {
        // Open loop, then closed loop (`evaluate_scene`).
        let [o, c] = &r.flown[..] else {
            continue;
        };
        let line: Vec<String> = r
            .segments
            .iter()
            .enumerate()
            .map(|(i, seg)| {
                format!(
                    "{:.1} – {:.1} m: {} / {} ({})",
                    seg.x0_m,
                    seg.x1_m,
                    o.segment_captures[i],
                    c.segment_captures[i],
                    bound(seg.truth.target_m, seg.truth.target_at_least),
                )
            })
            .collect();
        let _ = writeln!(s, "- {}: {}", r.name, line.join("; "));
    }

    let _ = writeln!(s, "\n### At equal captures: the worst segment\n");
    let _ = writeln!(s, "Each method's spacing scaled to the occlusion-aware count (the `equal` setting); worst and mean over segments of the segment's mean quality.\n");
    let _ = writeln!(s, "| scene | method | captures | (a) PSNR worst / mean | (b) PSNR worst / mean | (a) SSIM worst / mean | (b) SSIM worst / mean | worst unseen | worst parallax (px) |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in results {
        for (m, model) in METHODS.iter().enumerate() {
            let run = &r.runs[m][1];
            let _ = writeln!(
                s,
                "| {} | {} | {} |",
                r.name,
                model.as_str(),
                worst_segment_cells(run)
            );
        }
    }
    let _ = writeln!(
        s,
        "\n### The quality model at equal captures: the worst segment\n"
    );
    let _ = writeln!(s, "The quality model (the daemon's default, the truth's targets) at its own spacing; MMDS, the occlusion model and fixed-distance triggering scaled to its count. Worst and mean over segments of the segment's mean quality; worst unseen fraction and parallax over every in-between view; fewest captures seeing a sampled point. The last column: the quality model's worst segment against MMDS's, PSNR (a) / (b) in dB.\n");
    let _ = writeln!(s, "| scene | method | captures | (a) PSNR worst / mean | (b) PSNR worst / mean | (a) SSIM worst / mean | (b) SSIM worst / mean | worst unseen | worst parallax (px) | fewest views | worst vs MMDS (dB) |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in results {
        let worst = |run: &crate::eval::MethodRun, k: usize| {
            run.segment_psnr_db
                .iter()
                .map(|p| p[k])
                .fold(f64::INFINITY, f64::min)
        };
        let mmds = r.quality_equal.iter().find(|e| e.method == "mmds");
        for e in &r.quality_equal {
            let run = &e.run;
            let versus = match (e.method, mmds) {
                ("quality", Some(m)) => format!(
                    "{:+.2} / {:+.2}",
                    worst(run, 0) - worst(&m.run, 0),
                    worst(run, 1) - worst(&m.run, 1)
                ),
                _ => String::new(),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                r.name,
                e.method,
                worst_segment_cells(run),
                e.min_views.map_or("–".into(), |v| v.to_string()),
                versus,
            );
        }
    }
    if results.iter().any(|r| !r.colmap.is_empty()) {
        let _ = writeln!(s, "\n### COLMAP as a second judge, at equal captures\n");
        let _ = writeln!(s, "`scripts/colmap_judge.py` (pycolmap, CPU): SIFT with the known intrinsics, sequential matching, incremental mapping on each method's captures at the occlusion-aware count, and on the quality model's at its own spacing (`quality`) with MMDS scaled to that count (`mmds@quality`). Centres against the truth after a similarity; completeness: the fraction of the scene's occluded surface samples (visible from less than half of the line) with a triangulated point within 0.5 m.\n");
        let _ = writeln!(s, "| scene | method | registered / images | reprojection (px) | 3-D points | centre error median (m) | rotation error median (°) | completeness |");
        let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|");
        for r in results {
            for (m, v) in &r.colmap {
                match v {
                    Ok(j) => {
                        let g = |k: &str| j[k].as_f64();
                        let comp = &j["completeness"];
                        let _ = writeln!(
                            s,
                            "| {} | {} | {} / {} | {} | {} | {} | {} | {} |",
                            r.name,
                            m,
                            j["images_registered"],
                            j["images_total"],
                            f(g("mean_reprojection_px"), 2),
                            j["points3d"],
                            f(j["centre_error_m"]["median"].as_f64(), 3),
                            f(j["rotation_error_deg"]["median"].as_f64(), 2),
                            match (comp["covered"].as_u64(), comp["points"].as_u64()) {
                                (Some(c), Some(n)) if n > 0 =>
                                    format!("{c} / {n} = {:.3}", c as f64 / n as f64),
                                (_, Some(0)) => "no occluded samples".into(),
                                _ => "–".into(),
                            }
                        );
                    }
                    Err(e) => {
                        let _ = writeln!(
                            s,
                            "| {} | {} | not run: {} | | | | | |",
                            r.name,
                            m,
                            e.replace('|', "/")
                        );
                    }
                }
            }
        }
    }
    s.push('\n');
    s
}

/// A run's equal-capture cells: captures, PSNR and SSIM worst / mean over segments per
/// renderer, worst unseen fraction and worst parallax over its in-between views.
fn worst_segment_cells(run: &crate::eval::MethodRun) -> String {
    let wm = |v: Vec<f64>, d: usize| {
        let w = v.iter().copied().fold(f64::INFINITY, f64::min);
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        format!("{w:.d$} / {mean:.d$}")
    };
    format!(
        "{} | {} | {} | {} | {} | {:.4} | {}",
        run.captures.len(),
        wm(run.segment_psnr_db.iter().map(|p| p[0]).collect(), 2),
        wm(run.segment_psnr_db.iter().map(|p| p[1]).collect(), 2),
        wm(run.segment_ssim.iter().map(|p| p[0]).collect(), 4),
        wm(run.segment_ssim.iter().map(|p| p[1]).collect(), 4),
        run.segment_geo
            .iter()
            .map(|g| g.unseen_worst)
            .fold(0.0, f64::max),
        f(
            run.segment_geo
                .iter()
                .filter_map(|g| g.parallax_worst_px)
                .reduce(f64::max),
            2
        ),
    )
}

/// Relative error of a prediction against the truth; `None` where the truth is below a tenth
/// of the target (a relative error there measures nothing but the truth's smallness).
fn relative_error(pred: Option<f64>, truth: Option<f64>, target: f64) -> Option<f64> {
    match (pred, truth) {
        (Some(p), Some(t)) if t >= 0.1 * target && p.is_finite() => Some((p - t).abs() / t),
        _ => None,
    }
}

/// Issue 13's geometry accuracy: at each segment's target spacing, the quality model's
/// parallax and unseen fraction against the truth's worst interval, open loop and closed loop
/// separately, median and worst relative error on held-in and held-out scenes.
pub fn geometry_accuracy(results: &[SceneResult]) -> String {
    let t = crate::eval::truth::DEFAULT_TARGETS;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\n### Geometry at the target spacing: the quality model against the truth\n"
    );
    let _ = writeln!(s, "At each segment's target spacing, the worst interval's parallax span (px) and unseen fraction by the truth against the quality model's: open loop (`Estimate::predict_at` from the depth of each interval's middle frame, for captures half the spacing either side, where that middle view is in the segment) and closed loop (`core::closedloop` on the kept sensor depth of the interval's two captures and middle frame), each worst over the intervals the truth judges. Relative error |pred − truth| / truth, median / worst (segments); segments whose truth is below a tenth of the target are left out of the ratio and counted, with the largest prediction there in units of the target (a prediction above 1 there would be a false alarm: a capture too early).\n");
    let _ = writeln!(s, "The target spacing is mostly the parallax target's, so the truth's unseen fraction there is below a tenth of its target on nearly every segment and measures nothing. The unseen fraction is therefore also judged where it matters: at the first spacing (whole view steps, found by the sweep and its bisection) at which the truth's worst in-between view of the segment exceeds the unseen target, the same predictions (open and closed loop, worst interval) against the truth's worst (the rows \"where the truth exceeds the target\"; segments whose unseen fraction never exceeds it within the sweep are left out).\n");
    let _ = writeln!(s, "| quantity | loop | held in: median / worst (n) | held out: median / worst (n) | truth < target/10: n, largest prediction / target |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|");
    type Pick = fn(&crate::eval::SegmentTruth) -> (Option<f64>, Option<f64>);
    let rows: [(&str, &str, f64, Pick); 6] = [
        ("parallax", "open", t.parallax_px, |x| {
            (x.parallax_open_px, x.parallax_truth_px)
        }),
        ("parallax", "closed", t.parallax_px, |x| {
            (x.parallax_closed_px, x.parallax_truth_px)
        }),
        ("unseen fraction", "open", t.unseen_fraction_max, |x| {
            (x.unseen_open, x.unseen_truth)
        }),
        ("unseen fraction", "closed", t.unseen_fraction_max, |x| {
            (x.unseen_closed, x.unseen_truth)
        }),
        (
            "unseen fraction, where the truth exceeds the target",
            "open",
            t.unseen_fraction_max,
            |x| {
                let u = x.unseen_exceeded;
                (u.and_then(|u| u.open), u.map(|u| u.truth))
            },
        ),
        (
            "unseen fraction, where the truth exceeds the target",
            "closed",
            t.unseen_fraction_max,
            |x| {
                let u = x.unseen_exceeded;
                (u.and_then(|u| u.closed), u.map(|u| u.truth))
            },
        ),
    ];
    for (name, lp, target, pick) in rows {
        let cell = |inside: bool| {
            let mut v: Vec<f64> = results
                .iter()
                .filter(|r| CALIBRATION_FIT.contains(&r.name.as_str()) == inside)
                .flat_map(|r| r.segments.iter())
                .filter_map(|seg| {
                    let (p, tr) = pick(&seg.truth);
                    relative_error(p, tr, target)
                })
                .collect();
            if v.is_empty() {
                return "–".to_string();
            }
            v.sort_by(f64::total_cmp);
            format!(
                "{:.1} % / {:.1} % ({})",
                100.0 * v[v.len() / 2],
                100.0 * v[v.len() - 1],
                v.len()
            )
        };
        let small: Vec<f64> = results
            .iter()
            .flat_map(|r| r.segments.iter())
            .filter_map(|seg| {
                let (p, tr) = pick(&seg.truth);
                match tr {
                    Some(tr) if tr < 0.1 * target => Some(p.unwrap_or(0.0) / target),
                    _ => None,
                }
            })
            .collect();
        let _ = writeln!(
            s,
            "| {name} | {lp} | {} | {} | {}, {} |",
            cell(true),
            cell(false),
            small.len(),
            small
                .iter()
                .copied()
                .reduce(f64::max)
                .map_or("–".into(), |m| format!("{m:.2}"))
        );
    }
    let _ = writeln!(
        s,
        "\nPer segment (pred open / closed / truth): parallax px; unseen fraction; the unseen fraction where the truth first exceeds its target (at that spacing, m).\n"
    );
    for r in results {
        for seg in &r.segments {
            let x = &seg.truth;
            let _ = writeln!(
                s,
                "- {} {:.1} – {:.1} m (target {}): parallax {} / {} / {}; unseen {} / {} / {}; {}",
                r.name,
                seg.x0_m,
                seg.x1_m,
                f(x.target_m, 2),
                f(x.parallax_open_px, 2),
                f(x.parallax_closed_px, 2),
                f(x.parallax_truth_px, 2),
                f(x.unseen_open, 4),
                f(x.unseen_closed, 4),
                f(x.unseen_truth, 4),
                x.unseen_exceeded
                    .map_or("never exceeded".into(), |u| format!(
                        "at {:.2} m {} / {} / {:.4}",
                        u.spacing_m,
                        f(u.open, 4),
                        f(u.closed, 4),
                        u.truth
                    )),
            );
        }
    }
    s
}
