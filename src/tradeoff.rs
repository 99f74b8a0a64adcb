//! Error against run time: every decimation level and model measured on a set
//! of depth frames, against full resolution. Timing happens here, at the edge;
//! the core only computes.

use crate::core::estimate::{relative_error, relative_excess};
use crate::core::{DepthImage, Estimator, EstimatorParams, Intrinsics, Model};
use std::time::Instant;

/// One depth frame to measure on.
pub struct Frame {
    pub name: String,
    pub image: DepthImage,
    pub intrinsics: Intrinsics,
    pub pitch_rad: f64,
}

#[derive(Debug, Clone)]
pub struct Row {
    pub model: Model,
    pub decimation: usize,
    pub mean_error: f64,
    pub max_error: f64,
    /// Per frame, in the order of the frames.
    pub errors: Vec<f64>,
    /// Median time per frame, microseconds, averaged over frames.
    pub time_us: f64,
    /// Occlusion model only: mean and max relative error of the occlusion
    /// density `ρ`, which decimation distorts even where MMDS binds.
    pub density_error: Option<(f64, f64)>,
    /// Per frame, where the occlusion term was computed.
    pub density_errors: Vec<f64>,
}

fn time_us(est: &mut Estimator, f: &Frame, step: usize, repeats: usize) -> f64 {
    let mut t = Vec::with_capacity(repeats);
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        let e = est.estimate_at(&f.image, &f.intrinsics, f.pitch_rad, step);
        std::hint::black_box(&e);
        t.push(start.elapsed().as_secs_f64() * 1e6);
    }
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// Rows for each model in `models` and level in `levels`; the score (eq. 15)
/// is left out since it does not change the spacing.
pub fn measure(
    frames: &[Frame],
    base: &EstimatorParams,
    models: &[Model],
    levels: &[usize],
    repeats: usize,
) -> Vec<Row> {
    let mut rows = Vec::new();
    for &model in models {
        let params = EstimatorParams {
            model,
            score: None,
            with_sspa: false,
            with_occlusion: false,
            ..base.clone()
        };
        let mut est = Estimator::new(params);
        let run = |est: &mut Estimator, f: &Frame, level: usize| {
            est.estimate_at(&f.image, &f.intrinsics, f.pitch_rad, level)
                .ok()
                .map(|e| {
                    (
                        e.spacing.permissible_m,
                        e.occlusion.map(|o| o.density_per_m),
                    )
                })
                .unwrap_or((None, None))
        };
        let reference: Vec<_> = frames.iter().map(|f| run(&mut est, f, 1)).collect();
        for &level in levels {
            let mut errors = Vec::with_capacity(frames.len());
            let mut density_errors = Vec::new();
            let mut total_us = 0.0;
            for (f, r) in frames.iter().zip(&reference) {
                let got = run(&mut est, f, level);
                errors.push(relative_error(got.0, r.0));
                if let (Some(d), Some(dr)) = (got.1, r.1) {
                    // Both zero (no boundary at either level) is no error.
                    let positive = |x: f64| (x > 0.0).then_some(x);
                    density_errors.push(relative_error(positive(d), positive(dr)));
                }
                total_us += time_us(&mut est, f, level, repeats);
            }
            let n = errors.len().max(1) as f64;
            rows.push(Row {
                model,
                decimation: level,
                mean_error: errors.iter().sum::<f64>() / n,
                max_error: errors.iter().cloned().fold(0.0, f64::max),
                errors,
                time_us: total_us / n,
                density_error: (!density_errors.is_empty()).then(|| {
                    let m = density_errors.len() as f64;
                    (
                        density_errors.iter().sum::<f64>() / m,
                        density_errors.iter().cloned().fold(0.0, f64::max),
                    )
                }),
                density_errors,
            });
        }
    }
    rows
}

/// The table in markdown: error and time, and the speed-up against level 1 of
/// the same model measured in the same run.
pub fn markdown(frames: &[Frame], rows: &[Row]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| model | decimation | mean spacing error | max spacing error | occlusion density error (mean / max) | time per frame (µs) | speed-up vs 1 |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let full = rows
            .iter()
            .find(|x| x.model == r.model && x.decimation == 1)
            .map_or(f64::NAN, |x| x.time_us);
        let density = r.density_error.map_or("–".to_string(), |(m, x)| {
            format!("{} / {}", pct(m), pct(x))
        });
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {:.0} | {:.1}× |",
            r.model.as_str(),
            r.decimation,
            pct(r.mean_error),
            pct(r.max_error),
            density,
            r.time_us,
            full / r.time_us
        );
    }
    let _ = writeln!(s);
    let _ = write!(s, "| model | decimation |");
    for f in frames {
        let _ = write!(s, " {} |", f.name);
    }
    let _ = writeln!(s);
    let _ = writeln!(s, "|---|---:|{}", "---:|".repeat(frames.len()));
    for r in rows {
        let _ = write!(s, "| {} | {} |", r.model.as_str(), r.decimation);
        for e in &r.errors {
            let _ = write!(s, " {} |", pct(*e));
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s);
    let _ = writeln!(s, "Occlusion density error per frame:\n");
    let _ = write!(s, "| decimation |");
    for f in frames {
        let _ = write!(s, " {} |", f.name);
    }
    let _ = writeln!(s);
    let _ = writeln!(s, "|---:|{}", "---:|".repeat(frames.len()));
    for r in rows
        .iter()
        .filter(|r| r.density_errors.len() == frames.len())
    {
        let _ = write!(s, "| {} |", r.decimation);
        for e in &r.density_errors {
            let _ = write!(s, " {} |", pct(*e));
        }
        let _ = writeln!(s);
    }
    s
}

/// The visibility sweep's own sampling (`estimator.visibility_samples_max`):
/// for each cap, the relative error of the views-per-point and unseen-fraction
/// spacings against the sweep on every sample of the estimate's grid, the
/// largest excess of the views spacing over it (the unsafe direction), and the
/// time of the whole quality estimate, per frame. Both profiles' targets (the
/// mapping profile's k = 3 makes the views bound bind on more frames).
pub fn visibility_markdown(
    frames: &[Frame],
    base: &EstimatorParams,
    caps: &[usize],
    repeats: usize,
) -> String {
    use std::fmt::Write;
    let params = |cap: usize| EstimatorParams {
        model: Model::Quality,
        visibility_samples_max: cap,
        score: None,
        with_sspa: false,
        with_occlusion: false,
        ..base.clone()
    };
    let spacings = |est: &mut Estimator, f: &Frame| {
        est.estimate_at(&f.image, &f.intrinsics, f.pitch_rad, 1)
            .ok()
            .map_or((None, None), |e| (e.spacing.views_m, e.spacing.unseen_m))
    };
    let mut full = Estimator::new(params(usize::MAX));
    let reference: Vec<_> = frames.iter().map(|f| spacings(&mut full, f)).collect();
    let full_us: Vec<f64> = frames
        .iter()
        .map(|f| time_us(&mut full, f, 1, repeats))
        .collect();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| visibility samples (max) | views spacing error (mean / max) | views spacing longer (worst) | unseen spacing error (mean / max) | time per frame (µs) | speed-up vs every sample |"
    );
    let _ = writeln!(s, "|---:|---:|---:|---:|---:|---:|");
    for &cap in caps {
        let mut est = Estimator::new(params(cap));
        let (mut ve, mut ue, mut t, mut longer) = (Vec::new(), Vec::new(), 0.0, 0.0f64);
        for (k, f) in frames.iter().enumerate() {
            let (v, u) = spacings(&mut est, f);
            ve.push(relative_error(v, reference[k].0));
            ue.push(relative_error(u, reference[k].1));
            longer = longer.max(relative_excess(v, reference[k].0));
            t += time_us(&mut est, f, 1, repeats);
        }
        let n = frames.len().max(1) as f64;
        let stats = |e: &[f64]| {
            format!(
                "{} / {}",
                pct(e.iter().sum::<f64>() / n),
                pct(e.iter().cloned().fold(0.0, f64::max))
            )
        };
        let label = if cap == usize::MAX {
            "every sample".to_string()
        } else {
            cap.to_string()
        };
        let _ = writeln!(
            s,
            "| {label} | {} | {} | {} | {:.0} | {:.1}× |",
            stats(&ve),
            pct(longer),
            stats(&ue),
            t / n,
            full_us.iter().sum::<f64>() / t
        );
    }
    s
}

fn pct(x: f64) -> String {
    if x.is_finite() {
        format!("{:.2} %", 100.0 * x)
    } else {
        "lost".into()
    }
}

/// The synthetic reference scenes ([`crate::synth::reference_scenes`]) rendered
/// as Z16 at `width`×`height` (sky becomes "no return", as on a RealSense).
pub fn reference_frames(width: usize, height: usize, hfov_deg: f64) -> Vec<Frame> {
    use crate::core::DepthData;
    let intrinsics = Intrinsics::from_hfov_deg(width, height, hfov_deg, None)
        .expect("reference intrinsics are in range");
    crate::synth::reference_scenes()
        .into_iter()
        .map(|(name, world, pose)| {
            let depth = world.render_depth(&pose, &intrinsics);
            let data = crate::synth::to_z16(&depth, 0.001);
            Frame {
                name: name.to_string(),
                image: DepthImage::new(
                    width,
                    height,
                    DepthData::Z16 {
                        data,
                        scale_m: 0.001,
                    },
                )
                .expect("rendered size matches"),
                intrinsics,
                pitch_rad: pose.pitch_rad,
            }
        })
        .collect()
}
