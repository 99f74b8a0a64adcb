//! The ground-truth evaluation (DESIGN §3, `alfd eval`): dense views of each
//! scene along its survey line, captures chosen online by each method with the
//! daemon's trigger, every in-between view reconstructed by both renderers and
//! scored (PSNR, SSIM on luminance), the empirical permissible spacing per
//! segment beside each model's prediction, and the reports. Method and
//! reading: `docs/eval.md`.

pub mod plan;
pub(crate) mod plot;
pub mod recon;
mod report;

use crate::core::{Estimate, Estimator, EstimatorParams, Model};
use crate::metrics::{psnr, ssim};
use crate::render::{render, survey_camera, RenderOptions, SensorModel};
use crate::scene::{Scene, SceneError};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use recon::{Geometry, View};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;
use thiserror::Error;

/// The methods compared, in table order.
pub const METHODS: [Model; 4] = [Model::Occlusion, Model::Mmds, Model::Sspa, Model::Fixed];
pub const RENDERERS: [&str; 2] = ["lightfield", "warp"];
pub const SETTINGS: [&str; 2] = ["own", "equal"];
/// The five scenes of `scenes/`, in table order.
pub const SCENES: [&str; 5] = ["roof", "building", "tree", "edifice", "open"];
/// Scenes the `O_max` calibration fits on; the others are held out.
pub const CALIBRATION_FIT: [&str; 3] = ["roof", "building", "tree"];
/// Identical images have infinite PSNR; averages cap each view here.
pub const PSNR_CAP_DB: f64 = 100.0;
/// Tolerances of the empirical permissible spacing against dense sampling:
/// the 0.5 dB first, then looser ones to show how much the answer
/// depends on it.
pub const TOLERANCES_DB: [f64; 4] = [0.5, 1.0, 2.0, 0.5];
/// The criterion of [`TOLERANCES_DB`] whose reference is the densely sampled
/// light field of the literature (at most 1 px of disparity between adjacent
/// captures at the nearest depth) rather than the finest swept spacing.
pub const DENSE_CRITERION: usize = 3;
/// Segments per scene for the empirical permissible spacing.
pub const SEGMENTS: usize = 4;
/// Spacings swept, in dense-view steps (2 steps is the reference).
const LADDER: [usize; 12] = [2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96];

#[derive(Debug, Error)]
pub enum EvalError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("writing {path}: {message}")]
    Write { path: String, message: String },
    #[error("unknown scene {0}: the scenes are roof, building, tree, edifice, open")]
    UnknownScene(String),
}

/// What to run.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    pub scenes_dir: PathBuf,
    pub out_dir: PathBuf,
    /// Scene names; empty means all five.
    pub scenes: Vec<String>,
    /// A third of the resolution, three times the view step: a CI-sized run.
    pub quick: bool,
    pub progress: bool,
    /// Also write the decimation table (`decimation.md`).
    pub decimation_table: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            scenes_dir: PathBuf::from("scenes"),
            out_dir: PathBuf::from("eval"),
            scenes: Vec::new(),
            quick: false,
            progress: true,
            decimation_table: true,
        }
    }
}

/// Resolution and view density of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resolution {
    pub width: usize,
    pub height: usize,
    pub view_step_m: f64,
    pub supersample: usize,
}

impl Resolution {
    pub fn of(scene: &Scene, quick: bool) -> Resolution {
        let s = &scene.survey;
        let k = if quick { 3 } else { 1 };
        Resolution {
            width: (s.width / k).max(16),
            height: (s.height / k).max(16),
            view_step_m: s.view_step_m * k as f64,
            supersample: 2,
        }
    }
}

/// Reconstruction scores of one in-between view, per renderer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    pub psnr_db: [f64; 2],
    pub ssim: [f64; 2],
}

/// The per-view quantities of the estimator that the evaluation keeps.
#[derive(Debug, Clone, Copy, Default)]
pub struct ViewEstimate {
    /// Chosen spacing per method (index of [`METHODS`]).
    pub chosen_m: [Option<f64>; 4],
    /// Permissible spacing (before config limits) per method.
    pub permissible_m: [Option<f64>; 4],
    pub mmds_m: Option<f64>,
    pub density_per_m: f64,
    pub w_min: Option<f64>,
    pub w_max: Option<f64>,
}

/// One method in one setting: its captures and scores.
#[derive(Debug, Clone)]
pub struct MethodRun {
    pub scale: f64,
    pub captures: Vec<usize>,
    /// Per dense view; `None` for captured views.
    pub scores: Vec<Option<Score>>,
    pub mean_psnr_db: [f64; 2],
    pub mean_ssim: [f64; 2],
    /// Mean PSNR per segment, per renderer.
    pub segment_psnr_db: Vec<[f64; 2]>,
}

/// The empirical permissible spacing of one segment.
#[derive(Debug, Clone)]
pub struct Segment {
    pub first: usize,
    pub last: usize,
    pub x0_m: f64,
    pub x1_m: f64,
    /// `(spacing_m, mean PSNR per renderer)` for each swept spacing.
    pub sweep: Vec<(f64, [f64; 2])>,
    /// Largest spacing within each tolerance of [`TOLERANCES_DB`], per renderer.
    pub empirical_m: [[f64; 2]; 4],
    /// The sweep never left the tolerance (the true value is at least this).
    pub at_least: [[bool; 2]; 4],
    /// Dense sampling (1 px of disparity per step at the median `w_max`), m,
    /// and the swept spacing used as its reference.
    pub dense_m: f64,
    pub dense_reference_m: f64,
    /// Median over the segment's views of each method's permissible spacing.
    pub predicted_m: [Option<f64>; 4],
    /// Median occlusion density and MMDS, for the `O_max` calibration.
    pub densities: Vec<f64>,
    pub mmds: Vec<Option<f64>>,
}

#[derive(Debug, Clone)]
pub struct SceneResult {
    pub name: String,
    pub description: String,
    pub res: Resolution,
    pub views: usize,
    pub xs: Vec<f64>,
    pub estimates: Vec<ViewEstimate>,
    pub segments: Vec<Segment>,
    /// Spacing safe for the worst segment (renderer a), the fixed method's.
    pub safe_spacing_m: f64,
    /// `[method][setting]`.
    pub runs: Vec<[MethodRun; 2]>,
    pub elapsed_s: f64,
    pub render_s: f64,
}

/// Estimator parameters of one method: the defaults of the core (so the
/// evaluation judges what the daemon runs), no pitch score.
pub fn method_params(model: Model, fixed_spacing_m: f64) -> EstimatorParams {
    EstimatorParams {
        model,
        score: None,
        with_sspa: true,
        with_occlusion: true,
        fixed_spacing_m,
        ..EstimatorParams::default()
    }
}

/// The depth sensor of the evaluation: Z16 in 2 mm units (131 m of range, for
/// the tilted views), no noise, no dropout.
pub fn eval_sensor() -> SensorModel {
    SensorModel {
        scale_m: 0.002,
        ..SensorModel::default()
    }
}

fn view_estimate(
    ests: &mut [Estimator],
    img: &crate::core::DepthImage,
    g: &Geometry,
) -> ViewEstimate {
    let intr = crate::core::Intrinsics::from_focal_px(
        g.width,
        g.height,
        g.focal_px,
        Some((g.cx_px, g.cy_px)),
    )
    .expect("valid intrinsics");
    let mut v = ViewEstimate::default();
    for (m, est) in ests.iter_mut().enumerate() {
        let e: Estimate = est
            .estimate_at(img, &intr, g.pitch_rad, 1)
            .expect("frame and intrinsics match");
        v.chosen_m[m] = e.spacing.chosen_m.filter(|_| e.is_ok());
        v.permissible_m[m] = e.spacing.permissible_m.filter(|_| e.is_ok());
        if m == 0 {
            v.mmds_m = e.spacing.mmds_m;
            v.density_per_m = e.occlusion.map_or(0.0, |o| o.density_per_m);
            v.w_min = e.inv_depth.map(|i| i.min_per_m);
            v.w_max = e.inv_depth.map(|i| i.max_per_m);
        }
    }
    v
}

/// `w_opt` of an interval: the middle of the inverse-depth range both ends see.
fn w_opt(e: &[(Option<f64>, Option<f64>)], i: usize, j: usize) -> f64 {
    let lo = [e[i].0, e[j].0]
        .into_iter()
        .flatten()
        .fold(f64::INFINITY, f64::min);
    let hi = [e[i].1, e[j].1].into_iter().flatten().fold(0.0, f64::max);
    if lo.is_finite() && hi > 0.0 {
        0.5 * (lo + hi)
    } else {
        0.0
    }
}

struct Scorer<'a> {
    g: Geometry,
    views: &'a [View],
    /// `(w_min, w_max)` of each view.
    est: &'a [(Option<f64>, Option<f64>)],
    /// Scores per interval, and whether SSIM was computed.
    cache: HashMap<(usize, usize), (bool, Vec<Score>)>,
    pb: &'a ProgressBar,
}

impl Scorer<'_> {
    /// Scores every in-between view of the intervals not scored yet; SSIM
    /// (the costly part) only when `with_ssim`.
    fn ensure(&mut self, intervals: &[(usize, usize)], with_ssim: bool) {
        let mut todo: Vec<(usize, usize)> = intervals
            .iter()
            .copied()
            .filter(|&(i, j)| {
                j > i + 1
                    && match self.cache.get(&(i, j)) {
                        None => true,
                        Some((has_ssim, _)) => with_ssim && !has_ssim,
                    }
            })
            .collect();
        todo.sort_unstable();
        todo.dedup();
        let tasks: Vec<(usize, usize, usize)> = todo
            .iter()
            .flat_map(|&(i, j)| (i + 1..j).map(move |k| (i, j, k)))
            .collect();
        self.pb.inc_length(tasks.len() as u64);
        let (g, views, est, pb) = (self.g, self.views, self.est, self.pb);
        let scores: Vec<Score> = tasks
            .par_iter()
            .map(|&(i, j, k)| {
                let w = w_opt(est, i, j);
                let truth = &views[k].lum;
                let x = views[k].x_m;
                let a = recon::lightfield(&g, &views[i], &views[j], x, w);
                let b = recon::warp(&g, &views[i], &views[j], x, w);
                let q = |img: &[f32]| {
                    if with_ssim {
                        ssim(img, truth, g.width, g.height, 1.0).unwrap_or(f64::NAN)
                    } else {
                        f64::NAN
                    }
                };
                let s = Score {
                    psnr_db: [
                        psnr(&a, truth, 1.0).min(PSNR_CAP_DB),
                        psnr(&b, truth, 1.0).min(PSNR_CAP_DB),
                    ],
                    ssim: [q(&a), q(&b)],
                };
                pb.inc(1);
                s
            })
            .collect();
        let mut it = scores.into_iter();
        for (i, j) in todo {
            self.cache
                .insert((i, j), (with_ssim, it.by_ref().take(j - i - 1).collect()));
        }
    }

    /// Per-view scores of a capture list.
    fn per_view(&mut self, caps: &[usize], n: usize, with_ssim: bool) -> Vec<Option<Score>> {
        let intervals: Vec<_> = caps.windows(2).map(|w| (w[0], w[1])).collect();
        self.ensure(&intervals, with_ssim);
        let mut out = vec![None; n];
        for (i, j) in intervals {
            if let Some((_, s)) = self.cache.get(&(i, j)) {
                for (k, sc) in (i + 1..j).zip(s) {
                    out[k] = Some(*sc);
                }
            }
        }
        out
    }
}

fn mean(xs: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in xs {
        if x.is_finite() {
            s += x;
            n += 1;
        }
    }
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

fn median(mut xs: Vec<f64>) -> Option<f64> {
    xs.retain(|x| x.is_finite());
    if xs.is_empty() {
        return None;
    }
    xs.sort_by(f64::total_cmp);
    Some(xs[xs.len() / 2])
}

fn segment_bounds(n: usize) -> Vec<(usize, usize)> {
    (0..SEGMENTS)
        .map(|s| (s * (n - 1) / SEGMENTS, (s + 1) * (n - 1) / SEGMENTS))
        .collect()
}

fn summarise(
    scores: Vec<Option<Score>>,
    captures: Vec<usize>,
    scale: f64,
    segs: &[(usize, usize)],
) -> MethodRun {
    let pick = |r: usize, f: fn(&Score, usize) -> f64, lo: usize, hi: usize| {
        mean(scores[lo..=hi].iter().flatten().map(|s| f(s, r)))
    };
    let p = |s: &Score, r: usize| s.psnr_db[r];
    let q = |s: &Score, r: usize| s.ssim[r];
    let n = scores.len();
    MethodRun {
        scale,
        mean_psnr_db: [pick(0, p, 0, n - 1), pick(1, p, 0, n - 1)],
        mean_ssim: [pick(0, q, 0, n - 1), pick(1, q, 0, n - 1)],
        segment_psnr_db: segs
            .iter()
            .map(|&(a, b)| [pick(0, p, a, b), pick(1, p, a, b)])
            .collect(),
        captures,
        scores,
    }
}

/// Evaluates one scene.
pub fn evaluate_scene(scene: &Scene, res: Resolution, pb: &ProgressBar) -> SceneResult {
    let start = Instant::now();
    let s = &scene.survey;
    let n = ((s.end_x_m - s.start_x_m) / res.view_step_m + 1e-9).floor() as usize + 1;
    let xs: Vec<f64> = (0..n)
        .map(|k| s.start_x_m + k as f64 * res.view_step_m)
        .collect();
    let cam0 = survey_camera(scene, xs[0], res.width, res.height);
    let (cx, cy) = cam0.intrinsics.principal_px();
    let g = Geometry {
        width: res.width,
        height: res.height,
        focal_px: cam0.intrinsics.focal_px(),
        cx_px: cx,
        cy_px: cy,
        pitch_rad: s.pitch_rad,
    };
    pb.set_message(format!("{}: rendering {n} views", scene.name));
    pb.inc_length(n as u64);
    let opts = RenderOptions {
        supersample: res.supersample,
    };
    let sensor = eval_sensor();
    // Views render in parallel over rows inside; estimates are cheap.
    let mut views = Vec::with_capacity(n);
    let mut estimates = Vec::with_capacity(n);
    let mut ests: Vec<Estimator> = METHODS
        .iter()
        .map(|&m| Estimator::new(method_params(m, 1.0)))
        .collect();
    for &x in &xs {
        let frame = render(
            scene,
            &survey_camera(scene, x, res.width, res.height),
            &opts,
        );
        estimates.push(view_estimate(&mut ests, &frame.z16(&sensor), &g));
        views.push(View {
            x_m: x,
            lum: frame.luminance(),
            depth_m: frame.depth_m,
        });
        pb.inc(1);
    }
    let render_s = start.elapsed().as_secs_f64();
    let ranges: Vec<_> = estimates.iter().map(|e| (e.w_min, e.w_max)).collect();
    let mut scorer = Scorer {
        g,
        views: &views,
        est: &ranges,
        cache: HashMap::new(),
        pb,
    };

    // The empirical permissible spacing per segment.
    pb.set_message(format!("{}: sweeping spacings", scene.name));
    let segs = segment_bounds(n);
    let mut segments = Vec::new();
    for &(a, b) in &segs {
        let mut sweep = Vec::new();
        let mut failed = [[false; 2]; 4];
        let mut empirical = [[2.0 * res.view_step_m; 2]; 4];
        let mut reference = [[f64::NAN; 2]; 4];
        let w_max = median(estimates[a..=b].iter().filter_map(|e| e.w_max).collect());
        let gain = g.focal_px * s.pitch_rad.cos();
        let dense_m = w_max.map_or(f64::INFINITY, |w| 1.0 / (gain * w));
        let mut dense_reference_m = 2.0 * res.view_step_m;
        let predicted_m: [Option<f64>; 4] = std::array::from_fn(|m| {
            median(
                estimates[a..=b]
                    .iter()
                    .map(|e| e.permissible_m[m].unwrap_or(f64::INFINITY))
                    .collect(),
            )
        });
        let reach = [predicted_m[0], predicted_m[1]]
            .into_iter()
            .flatten()
            .filter(|p| p.is_finite())
            .fold(0.0, f64::max);
        for &k in LADDER.iter().filter(|&&k| 2 * k <= b - a) {
            let mut caps: Vec<usize> = (a..=b).step_by(k).collect();
            if *caps.last().unwrap() != b {
                caps.push(b);
            }
            let sc = scorer.per_view(&caps, n, false);
            let m = [
                mean(sc[a..=b].iter().flatten().map(|s| s.psnr_db[0])),
                mean(sc[a..=b].iter().flatten().map(|s| s.psnr_db[1])),
            ];
            let spacing = k as f64 * res.view_step_m;
            if k == 2 {
                reference = [m; 4];
            }
            // The dense reference moves up the ladder until dense sampling.
            if k > 2 && spacing <= dense_m * (1.0 + 1e-9) {
                reference[DENSE_CRITERION] = m;
                dense_reference_m = spacing;
            }
            for (t, tol) in TOLERANCES_DB.iter().enumerate() {
                for r in 0..2 {
                    if !failed[t][r] {
                        if m[r] >= reference[t][r] - tol {
                            empirical[t][r] = spacing;
                        } else {
                            failed[t][r] = true;
                        }
                    }
                }
            }
            sweep.push((spacing, m));
            // Past the first failure, the sweep goes on to the predictions it
            // is compared with, so the report shows the curve around them.
            if failed.iter().flatten().all(|f| *f) && spacing > 1.25 * reach {
                break;
            }
        }
        segments.push(Segment {
            first: a,
            last: b,
            x0_m: xs[a],
            x1_m: xs[b],
            sweep,
            empirical_m: empirical,
            at_least: failed.map(|f| f.map(|x| !x)),
            dense_m,
            dense_reference_m,
            predicted_m,
            densities: estimates[a..=b].iter().map(|e| e.density_per_m).collect(),
            mmds: estimates[a..=b].iter().map(|e| e.mmds_m).collect(),
        });
    }
    let safe_spacing_m = segments
        .iter()
        .map(|s| s.empirical_m[0][0])
        .fold(f64::INFINITY, f64::min);

    // The fixed method's spacing, through the estimator like the others:
    // `Model::Fixed` ignores the depth (one pixel will do) and applies the
    // config limits to `fixed_spacing_m`.
    let mut fixed = Estimator::new(method_params(Model::Fixed, safe_spacing_m));
    let intr = cam0.intrinsics;
    let depth0 = crate::core::DepthImage::new(
        1,
        1,
        crate::core::DepthData::Metres(vec![s.altitude_m as f32]),
    )
    .expect("1x1");
    let intr1 = crate::core::Intrinsics::from_focal_px(1, 1, intr.focal_px(), None).expect("1x1");
    let fixed_chosen = fixed
        .estimate_at(&depth0, &intr1, s.pitch_rad, 1)
        .ok()
        .and_then(|e| e.spacing.chosen_m);
    for e in estimates.iter_mut() {
        e.chosen_m[3] = fixed_chosen;
        e.permissible_m[3] = fixed_chosen;
    }
    for seg in segments.iter_mut() {
        seg.predicted_m[3] = fixed_chosen;
    }

    // Each method at its own spacing, then at the occlusion-aware count.
    pb.set_message(format!("{}: planning and scoring", scene.name));
    let spacing_of =
        |m: usize| -> Vec<Option<f64>> { estimates.iter().map(|e| e.chosen_m[m]).collect() };
    let own: Vec<Vec<usize>> = (0..METHODS.len())
        .map(|m| plan::captures(&spacing_of(m), res.view_step_m, s.speed_mps, 1.0))
        .collect();
    let target = own[0].len();
    let equal: Vec<(f64, Vec<usize>)> = (0..METHODS.len())
        .map(|m| {
            if m == 0 {
                (1.0, own[0].clone())
            } else {
                plan::scale_to_count(&spacing_of(m), res.view_step_m, s.speed_mps, target)
            }
        })
        .collect();
    let all: Vec<(usize, usize)> = own
        .iter()
        .chain(equal.iter().map(|e| &e.1))
        .flat_map(|c| c.windows(2).map(|w| (w[0], w[1])).collect::<Vec<_>>())
        .collect();
    scorer.ensure(&all, true);
    let mut runs = Vec::new();
    for m in 0..METHODS.len() {
        let o = scorer.per_view(&own[m], n, true);
        let e = scorer.per_view(&equal[m].1, n, true);
        runs.push([
            summarise(o, own[m].clone(), 1.0, &segs),
            summarise(e, equal[m].1.clone(), equal[m].0, &segs),
        ]);
    }
    SceneResult {
        name: scene.name.clone(),
        description: scene.description.clone(),
        res,
        views: n,
        xs,
        estimates,
        segments,
        safe_spacing_m,
        runs,
        elapsed_s: start.elapsed().as_secs_f64(),
        render_s,
    }
}

/// The `O_max` calibration: for each candidate, the mean absolute log error of
/// the occlusion-aware prediction `min(MMDS, O_max/ρ)` (median over each
/// segment's views) against the empirical spacing of renderer `r`, on the fit
/// scenes and on the held-out ones. Segments whose sweep never left the
/// tolerance are left out (their empirical value is only a lower bound).
pub fn calibrate_occlusion_max(
    results: &[SceneResult],
    r: usize,
    tol: usize,
) -> Vec<(f64, f64, usize, f64, usize)> {
    let candidates: Vec<f64> = (0..15).map(|k| 0.001 * 2f64.powf(k as f64 / 2.0)).collect();
    candidates
        .into_iter()
        .map(|o| {
            let mut fit = (0.0, 0usize);
            let mut held = (0.0, 0usize);
            for res in results {
                for seg in &res.segments {
                    if seg.at_least[tol][r] {
                        continue;
                    }
                    let pred = median(
                        seg.densities
                            .iter()
                            .zip(&seg.mmds)
                            .map(|(&rho, &mm)| {
                                let occ = if rho > 0.0 { o / rho } else { f64::INFINITY };
                                mm.unwrap_or(f64::INFINITY).min(occ)
                            })
                            .collect(),
                    );
                    let Some(p) = pred else { continue };
                    let err = (p / seg.empirical_m[tol][r]).ln().abs();
                    let acc = if CALIBRATION_FIT.contains(&res.name.as_str()) {
                        &mut fit
                    } else {
                        &mut held
                    };
                    acc.0 += err;
                    acc.1 += 1;
                }
            }
            let m = |a: (f64, usize)| if a.1 > 0 { a.0 / a.1 as f64 } else { f64::NAN };
            (o, m(fit), fit.1, m(held), held.1)
        })
        .collect()
}

/// The largest uniform spacing of the sweeps whose worst segment (renderer
/// `r`) still reaches `psnr_db`, and the captures fixed-distance triggering
/// needs at it over the whole line; `None` if even the finest does not.
pub fn fixed_at_equal_worst_case(
    res: &SceneResult,
    r: usize,
    psnr_db: f64,
) -> Option<(f64, usize)> {
    let first = res.segments.first()?;
    let mut best = None;
    for (k, &(spacing, _)) in first.sweep.iter().enumerate() {
        let worst = res
            .segments
            .iter()
            .map(|s| s.sweep.get(k).map_or(f64::NEG_INFINITY, |p| p.1[r]))
            .fold(f64::INFINITY, f64::min);
        if worst >= psnr_db {
            best = Some(spacing);
        } else {
            break;
        }
    }
    best.map(|b| {
        let length = res.xs.last().unwrap_or(&0.0) - res.xs[0];
        (b, (length / b - 1e-9).ceil() as usize + 1)
    })
}

/// Runs the evaluation and writes `results.json`, `report.md`, the plots and
/// (optionally) `decimation.md` into `opts.out_dir`. Returns the report path.
pub fn run(opts: &EvalOptions) -> Result<PathBuf, EvalError> {
    let start = Instant::now();
    let names: Vec<String> = if opts.scenes.is_empty() {
        SCENES.iter().map(|s| s.to_string()).collect()
    } else {
        opts.scenes.clone()
    };
    let mut scenes = Vec::new();
    for name in &names {
        if !SCENES.contains(&name.as_str()) && !Path::new(name).exists() {
            return Err(EvalError::UnknownScene(name.clone()));
        }
        let path = if Path::new(name).exists() {
            PathBuf::from(name)
        } else {
            opts.scenes_dir.join(format!("{name}.toml"))
        };
        scenes.push(Scene::load(&path)?);
    }
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| write_err(&opts.out_dir, e))?;
    let pb = if opts.progress {
        let pb = ProgressBar::new(0);
        pb.set_style(
            ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} {msg}")
                .expect("valid template")
                .progress_chars("=> "),
        );
        pb
    } else {
        ProgressBar::hidden()
    };
    let mut results = Vec::new();
    for scene in &scenes {
        let res = Resolution::of(scene, opts.quick);
        let mut scene = scene.clone();
        scene.scale_textures(res.width as f64 / scene.survey.width as f64);
        results.push(evaluate_scene(&scene, res, &pb));
    }
    pb.set_message("plots and reports");
    for r in &results {
        plot::scene_plots(r, &opts.out_dir).map_err(|e| EvalError::Write {
            path: opts.out_dir.display().to_string(),
            message: e,
        })?;
    }
    let decimation = if opts.decimation_table {
        let md = report::decimation_table(&scenes, opts.quick);
        let p = opts.out_dir.join("decimation.md");
        std::fs::write(&p, &md).map_err(|e| write_err(&p, e))?;
        Some(md)
    } else {
        None
    };
    let json = report::results_json(&results);
    let p = opts.out_dir.join("results.json");
    std::fs::write(
        &p,
        serde_json::to_string_pretty(&json).expect("json") + "\n",
    )
    .map_err(|e| write_err(&p, e))?;
    let md = report::markdown(
        &results,
        opts.quick,
        start.elapsed().as_secs_f64(),
        decimation.as_deref(),
    );
    let p = opts.out_dir.join("report.md");
    std::fs::write(&p, md).map_err(|e| write_err(&p, e))?;
    pb.finish_and_clear();
    Ok(p)
}

fn write_err(p: &Path, e: std::io::Error) -> EvalError {
    EvalError::Write {
        path: p.display().to_string(),
        message: e.to_string(),
    }
}
