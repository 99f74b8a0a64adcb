//! Estimates as the outside world reads them: the JSON object of DESIGN §4
//! (every number finite or null) and a short human summary.

use crate::capture::QualityRecord;
use crate::core::estimate::{DecimationChoice, NoEstimate};
use crate::core::{Estimate, EstimatorParams, Quality};
use serde_json::{json, Value};

/// A quantity for JSON: finite non-negative values pass, anything else is null.
fn num(x: Option<f64>) -> Value {
    match x {
        Some(v) if v.is_finite() && v >= 0.0 => json!(v),
        _ => Value::Null,
    }
}

/// What was estimated from, echoed so a result file stands on its own.
#[derive(Debug, Clone)]
pub struct InputInfo {
    pub file: String,
    pub format: &'static str,
    pub width: usize,
    pub height: usize,
    pub focal_px: f64,
    pub pitch_deg: f64,
    /// Metres per unit of a Z16 or PNG map (`None`: PFM, in metres).
    pub depth_scale_m: Option<f64>,
}

/// Why a frame gave no estimate, in words an operator can act on: for too few valid
/// pixels, how many were and how many lay beyond the depth camera's range (a RealSense's
/// 1 mm Z16 ends at 65.5 m: flown higher, every pixel is beyond it); for the pitch, the
/// pitch and the limit with its key.
pub fn no_estimate_reason(why: NoEstimate, e: &Estimate, params: &EstimatorParams) -> String {
    match why {
        NoEstimate::TooFewValidPixels if e.samples > 0 => {
            let share = |n: usize| 100.0 * n as f64 / e.samples as f64;
            format!(
                "{:.0} % of the depth valid, {:.0} % needed; {:.0} % beyond the depth camera's range",
                100.0 * e.valid_fraction,
                100.0 * params.valid_fraction_min,
                share(e.far_below_samples)
            )
        }
        NoEstimate::PitchNearHorizontal => format!(
            "pitch {:.1} deg is beyond estimator.pitch_max_deg ({:.1}): the camera looks along \
             the track, where the spacing model does not hold",
            e.pitch_rad.to_degrees(),
            params.pitch_max_rad.to_degrees()
        ),
        NoEstimate::InvalidPitch => "the attitude's pitch is not a number".into(),
        other => other.as_str().replace('_', " "),
    }
}

pub fn estimate_json(
    e: &Estimate,
    params: &EstimatorParams,
    decimation: Option<&DecimationChoice>,
    input: &InputInfo,
    elapsed_us: u64,
) -> Value {
    let ok = e.is_ok();
    let inv = e.inv_depth.filter(|_| ok);
    let occ = e.occlusion.filter(|_| ok);
    json!({
        "status": if ok { "ok" } else { "no_estimate" },
        "reason": e.no_estimate.map(|r| r.as_str()),
        "reason_text": e.no_estimate.map(|r| no_estimate_reason(r, e, params)),
        "valid_fraction": num(Some(e.valid_fraction)),
        "far_below_fraction": num(Some(if e.samples > 0 {
            e.far_below_samples as f64 / e.samples as f64
        } else {
            0.0
        })),
        "far_end_unbounded": e.terms.beyond_range,
        "inv_depth_per_m": inv.map(|i| json!({
            "min": num(Some(i.min_per_m)),
            "max": num(Some(i.max_per_m)),
            "opt": num(Some(i.opt_per_m)),
        })),
        "occlusion": occ.map(|o| json!({
            "boundaries": o.boundaries,
            "lines": o.lines,
            "contrast_per_m": num(Some(o.contrast_per_m)),
            "density_per_m": num(Some(o.density_per_m)),
            "degree": num(Some(o.degree)),
            "max_degree": num(Some(o.max_degree)),
        })),
        "quality": e.quality.filter(|_| ok).and_then(|_| {
            e.spacing.chosen_m.and_then(|c| QualityRecord::from_estimate(e, c))
        }),
        "visibility": e.visibility.filter(|_| ok).map(|v| json!({
            "samples": v.samples,
            "occluded_samples": v.occluded_samples,
            "occluded_lines": v.occluded_lines,
            "interval_min_m": num(v.interval_min_m),
            "occluded_interval_min_m": num(v.occluded_interval_min_m),
            "step": v.step,
            "interleave": v.interleave,
        })),
        "spacing_m": {
            "parallax": num(e.spacing.parallax_m),
            "forward_overlap": num(e.spacing.forward_overlap_m),
            "unseen_fraction": num(e.spacing.unseen_m),
            "views_per_point": num(e.spacing.views_m),
            "mmds": num(e.spacing.mmds_m),
            "sspa": num(e.spacing.sspa_m),
            "occlusion": num(e.spacing.occlusion_m),
            "coverage": num(e.spacing.coverage_m),
            "permissible": num(e.spacing.permissible_m),
            "chosen": num(e.spacing.chosen_m),
        },
        "active_bound": e.active_bound.map(|b| b.as_str()),
        "model": params.model.as_str(),
        "terms": e.terms.names(),
        // A pitch may be negative (tilted backwards); it is always finite.
        "best_pitch_deg": e.best_pitch.map(|s| s.pitch_rad.to_degrees()),
        "best_pitch_degree": num(e.best_pitch.map(|s| s.degree)),
        "decimation": {
            "level": e.decimation,
            "budget": decimation.map(|d| d.budget),
            "errors": decimation.map(|d| d.errors.iter().map(|(l, err)| json!({
                "level": l, "relative_error": num(Some(*err)),
            })).collect::<Vec<_>>()),
        },
        "input": {
            "file": input.file,
            "format": input.format,
            "width": input.width,
            "height": input.height,
            "focal_px": num(Some(input.focal_px)),
            "pitch_deg": input.pitch_deg,
            "depth_scale_m": input.depth_scale_m,
        },
        "elapsed_us": elapsed_us,
    })
}

/// The targets in force, as `alfd estimate` and `alfd sim` print them (the
/// summary has them from the manifest's record, not a [`Quality`]).
pub fn targets_text(
    parallax_px: Option<f64>,
    forward_overlap: Option<f64>,
    unseen_fraction_max: f64,
    views_per_point_min: u32,
) -> String {
    let opt = |x: Option<f64>, unit: &str| x.map_or("off".to_string(), |v| format!("{v}{unit}"));
    format!(
        "parallax {}, forward overlap {}, unseen {}, views >= {}",
        opt(parallax_px, " px"),
        opt(forward_overlap, ""),
        match unseen_fraction_max {
            Quality::UNSEEN_OFF => "off".to_string(),
            v => format!("<= {v}"),
        },
        views_per_point_min
    )
}

fn fmt_m(x: Option<f64>) -> String {
    match x {
        // Far beyond any depth camera (a PFM in other units, a bad scale):
        // thirty digits of a float's noise would say nothing more.
        Some(v) if v >= 1e5 => format!("{v:.3e} m"),
        Some(v) if v >= 100.0 => format!("{v:.1} m"),
        Some(v) if v >= 0.01 => format!("{v:.3} m"),
        Some(v) => format!("{v:.3e} m"),
        None => "unbounded".into(),
    }
}

pub fn estimate_text(
    e: &Estimate,
    params: &EstimatorParams,
    decimation: Option<&DecimationChoice>,
    input: &InputInfo,
    elapsed_us: u64,
) -> String {
    let mut s = String::new();
    use std::fmt::Write;
    let _ = writeln!(
        s,
        "{}: {}x{} {}, f = {:.1} px, pitch {:.1} deg, {:.1} % valid",
        input.file,
        input.width,
        input.height,
        input.format,
        input.focal_px,
        input.pitch_deg,
        100.0 * e.valid_fraction
    );
    if e.far_below_samples > 0 {
        let _ = writeln!(
            s,
            "no return      {:.1} % of samples below the horizon (ground beyond the range?){}",
            100.0 * e.far_below_samples as f64 / e.samples.max(1) as f64,
            if e.terms.beyond_range {
                ": the far end is taken at infinity"
            } else {
                ": within the percentile tail"
            }
        );
    }
    if let Some(r) = e.no_estimate {
        let _ = writeln!(s, "no estimate: {}", no_estimate_reason(r, e, params));
        return s;
    }
    if let Some(i) = e.inv_depth {
        let _ = writeln!(
            s,
            "depth range    {} to {} (robust {:.1}-{:.1} percentiles)",
            fmt_m(Some(1.0 / i.max_per_m)),
            if i.min_per_m > 0.0 {
                fmt_m(Some(1.0 / i.min_per_m))
            } else if e.terms.beyond_range {
                "beyond range".into()
            } else {
                "sky".into()
            },
            100.0 * params.percentile_low,
            100.0 * params.percentile_high
        );
    } else {
        let _ = writeln!(s, "depth range    no surface in view (sky only)");
    }
    if let Some(o) = e.occlusion {
        let _ = writeln!(
            s,
            "occlusion      {} boundaries on {} lines, density {:.4} /m, degree {:.4} (max {})",
            o.boundaries, o.lines, o.density_per_m, o.degree, o.max_degree
        );
    }
    let sp = &e.spacing;
    if let Some(q) = e.quality {
        let t = q.targets;
        let _ = writeln!(
            s,
            "targets        {} profile: {}",
            t.profile.as_str(),
            targets_text(
                t.parallax_px,
                t.forward_overlap,
                t.unseen_fraction_max,
                t.views_per_point_min
            )
        );
        if let Some(v) = e.visibility {
            let _ = writeln!(
                s,
                "visibility     {} of {} samples occluded on {} lines{}{}",
                v.occluded_samples,
                v.samples,
                v.occluded_lines,
                if v.step > 1 {
                    format!(", every {} px", v.step)
                } else {
                    String::new()
                },
                if v.occluded_samples == 0 {
                    " (term left out)"
                } else {
                    ""
                }
            );
        }
        // A row without a figure says why: the target is not in force, or it
        // is and this frame gave it nothing to bound (which `terms` leaves out).
        let row = |name: &str, on: bool, in_force: bool, m: Option<f64>, at: String| {
            if on {
                format!(
                    "spacing  {name:<16}{:<12} predicted at chosen: {at}\n",
                    fmt_m(m)
                )
            } else if !in_force {
                format!("spacing  {name:<16}off (not in force)\n")
            } else if e.inv_depth.is_none() {
                format!("spacing  {name:<16}left out: no surface in view\n")
            } else {
                format!("spacing  {name:<16}left out: nothing occludes\n")
            }
        };
        let pv = |x: Option<f64>, f: &dyn Fn(f64) -> String| x.map_or("n/a".into(), f);
        s.push_str(&row(
            "parallax",
            e.terms.parallax,
            t.parallax_px.is_some(),
            sp.parallax_m,
            pv(q.parallax_px, &|v| format!("{v:.2} px")),
        ));
        s.push_str(&row(
            "forward_overlap",
            e.terms.forward_overlap,
            t.forward_overlap.is_some(),
            sp.forward_overlap_m,
            pv(q.forward_overlap, &|v| format!("{:.1} %", 100.0 * v)),
        ));
        s.push_str(&row(
            "unseen_fraction",
            e.terms.visibility,
            t.unseen_fraction_max < Quality::UNSEEN_OFF,
            sp.unseen_m,
            pv(q.unseen_fraction, &|v| format!("{v:.5}")),
        ));
        s.push_str(&row(
            "views_per_point",
            e.terms.views,
            true,
            sp.views_m,
            // The count saturates where nothing bounds it (depth at infinity).
            q.views_per_point.map_or("n/a".into(), |k| match k {
                u32::MAX => "unbounded".into(),
                k => format!("{k} views"),
            }),
        ));
    }
    let _ = writeln!(s, "spacing  mmds      {}", fmt_m(sp.mmds_m));
    if e.terms.sspa {
        let _ = writeln!(s, "         sspa      {}", fmt_m(sp.sspa_m));
    }
    if e.terms.occlusion {
        let _ = writeln!(s, "         occlusion {}", fmt_m(sp.occlusion_m));
    }
    let _ = writeln!(s, "         coverage  {}", fmt_m(sp.coverage_m));
    let _ = writeln!(
        s,
        "chosen         {} ({} model, bound: {})",
        fmt_m(sp.chosen_m),
        params.model.as_str(),
        e.active_bound.map_or("none", |b| b.as_str())
    );
    // The figures above show the broken targets; this line says so.
    if let Some((_, permissible)) = e.floor_over_permissible() {
        let _ = writeln!(
            s,
            "               longer than the permissible {}: sampling.spacing_min_m holds it, so the targets are not met there",
            fmt_m(Some(permissible))
        );
    }
    let _ = writeln!(s, "terms          {}", e.terms.names().join(", "));
    if let Some(b) = e.best_pitch {
        let _ = writeln!(
            s,
            "best pitch     {:.1} deg (occlusion degree {:.4} there)",
            b.pitch_rad.to_degrees(),
            b.degree
        );
    }
    match decimation {
        Some(d) => {
            let errs: Vec<String> = d
                .errors
                .iter()
                .map(|(l, err)| {
                    if err.is_finite() {
                        format!("{l}: {:.2} %", 100.0 * err)
                    } else {
                        format!("{l}: n/a")
                    }
                })
                .collect();
            let _ = writeln!(
                s,
                "decimation     {} (coarsest within {:.1} %; errors {})",
                d.level,
                100.0 * d.budget,
                errs.join(", ")
            );
        }
        None => {
            let _ = writeln!(s, "decimation     {}", e.decimation);
        }
    }
    let min = params.grid_samples_min();
    let coarsest = crate::core::inverse::coarsest_step(input.width, input.height, min);
    // A frame too small even at every pixel is no stride's fault.
    if e.samples < min && e.decimation > coarsest {
        let _ = writeln!(
            s,
            "               {} of the frame at decimation {}, fewer than the {min} its {} % percentile needs: \
             the depth range is the extremes of a few samples (decimation {} at most for this frame)",
            if e.samples == 1 {
                "1 sample".to_owned()
            } else {
                format!("{} samples", e.samples)
            },
            e.decimation,
            100.0 * params.percentile_low,
            coarsest
        );
    }
    let _ = writeln!(s, "elapsed        {elapsed_us} us");
    s
}
