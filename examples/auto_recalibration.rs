//! What `decimation = "auto"`'s recalibration period buys and costs: along each
//! scene's survey line, 640×480 Z16 depth every 1/30 s at the scene's speed (the
//! daemon's 30 fps), the daemon's estimator (`[quality] profile = "lightfield"`, as `alfd sim`) with `auto`
//! recalibrated every `P` frames, against the estimate of the same frame at full
//! resolution with its visibility sweep over every pixel. Per period: the
//! estimator's time per frame as a ratio to reading the frame once (the sum of its
//! u16 values, timed on the same frames in the same run), the relative spacing
//! error of every frame against full resolution, and how much longer (the unsafe
//! side) it came out (`docs/performance.md`):
//! `cargo run --release --example auto_recalibration [-- scenes/district.toml ...]`
//! (default: `district` and the eight evaluation scenes).

#[path = "common/survey.rs"]
mod survey;

use alfd::core::estimate::{relative_error, relative_excess};
use alfd::core::{Decimation, Estimator, EstimatorParams};
use alfd::scene::Scene;
use std::hint::black_box;
use std::time::{Duration, Instant};

const W: usize = 640;
const H: usize = 480;
/// Recalibration periods studied, frames (`usize::MAX`: only the first frame).
const PERIODS: [usize; 6] = [1, 30, 90, 150, 300, usize::MAX];
const FIXED: [usize; 5] = [1, 2, 4, 8, 16];

#[derive(Default)]
struct Tally {
    time: Duration,
    errors: Vec<f64>,
    calibrations: usize,
    levels: Vec<usize>,
    /// The worst frame: its position, and each term's spacing at full
    /// resolution and as estimated.
    worst: Option<(f64, f64, String)>,
    /// The largest relative excess over full resolution, and the frames over 5 %.
    long: f64,
    long_frames: usize,
}

/// Each term's spacing of two estimates, `full → estimated`, m.
fn terms(full: &alfd::core::Estimate, e: &alfd::core::Estimate) -> String {
    let f = |x: Option<f64>| x.map_or("–".into(), |v| format!("{v:.2}"));
    let (a, b) = (&full.spacing, &e.spacing);
    format!(
        "parallax {} → {}, unseen {} → {}, views {} → {}, permissible {} → {}",
        f(a.parallax_m),
        f(b.parallax_m),
        f(a.unseen_m),
        f(b.unseen_m),
        f(a.views_m),
        f(b.views_m),
        f(a.permissible_m),
        f(b.permissible_m)
    )
}

impl Tally {
    fn add(&mut self, x_m: f64, full: &alfd::core::Estimate, e: &alfd::core::Estimate) {
        let err = relative_error(e.spacing.permissible_m, full.spacing.permissible_m);
        self.errors.push(err);
        // The unsafe direction: a spacing longer than full resolution's.
        let excess = relative_excess(e.spacing.permissible_m, full.spacing.permissible_m);
        self.long = self.long.max(excess);
        self.long_frames += (excess > 0.05) as usize;
        self.levels.push(e.decimation);
        if self.worst.as_ref().is_none_or(|w| err > w.1) {
            self.worst = Some((x_m, err, terms(full, e)));
        }
    }
}

impl Tally {
    fn row(&self, name: &str, read: Duration, budget: f64) {
        let mut e = self.errors.clone();
        e.sort_by(f64::total_cmp);
        let at = |q: f64| e[((e.len() - 1) as f64 * q).round() as usize];
        let over = e.iter().filter(|&&x| x > budget).count();
        let mut levels = self.levels.clone();
        levels.sort_unstable();
        levels.dedup();
        println!(
            "| {name} | {:.2}× | {} | {:.2} % | {:.2} % | {:.2} % | {} of {} | {:.1} %, {} | {:?} |",
            self.time.as_secs_f64() / read.as_secs_f64(),
            self.calibrations,
            100.0 * at(0.5),
            100.0 * at(0.99),
            100.0 * at(1.0),
            over,
            e.len(),
            100.0 * self.long,
            self.long_frames,
            levels,
        );
    }
}

fn main() -> anyhow::Result<()> {
    let paths = survey::scene_paths();
    // The daemon's estimator as `alfd sim` configures it (`[quality] profile`).
    // The sweep on every line of every frame: decimation's error alone, not
    // the flight default's spreading over frames (examples/visibility_interleave.rs).
    let base = EstimatorParams {
        visibility_interleave: 1,
        ..alfd::config::Config::from_text("[quality]\nprofile = \"lightfield\"\n", "sim")?.estimator
    };
    let Decimation::Auto { budget, levels, .. } = Decimation::auto() else {
        unreachable!()
    };
    for path in &paths {
        let scene = Scene::load(path)?;
        let s = scene.survey.clone();
        let sensor = survey::sensor(&scene);
        let n = survey::positions_m(&scene).count();
        // The reference sweeps every pixel (the daemon's own full estimate
        // thins the sweep to `visibility_samples_max`: the row "fixed 1").
        let mut reference = Estimator::new(EstimatorParams {
            visibility_samples_max: usize::MAX,
            ..base.clone()
        });
        let mut auto: Vec<(usize, Estimator, Tally)> = PERIODS
            .iter()
            .map(|&p| {
                let params = EstimatorParams {
                    decimation: Decimation::Auto {
                        budget,
                        levels: levels.clone(),
                        recalibrate_frames: p,
                    },
                    ..base.clone()
                };
                (p, Estimator::new(params), Tally::default())
            })
            .collect();
        let mut fixed: Vec<(usize, Estimator, Tally)> = FIXED
            .iter()
            .map(|&l| (l, Estimator::new(base.clone()), Tally::default()))
            .collect();
        let mut read = Duration::ZERO;
        for x in survey::positions_m(&scene) {
            let (img, intr) = survey::z16_at(&scene, x, (W, H), &sensor)?;
            read += survey::read_time(&img);
            let truth = reference.estimate_at(&img, &intr, s.pitch_rad, 1)?;
            for (_, est, tally) in auto.iter_mut() {
                let t = Instant::now();
                let (e, choice) = est.estimate(black_box(&img), &intr, s.pitch_rad)?;
                tally.time += t.elapsed();
                tally.calibrations += choice.is_some() as usize;
                tally.add(x, &truth, &e);
            }
            for (level, est, tally) in fixed.iter_mut() {
                let t = Instant::now();
                let e = est.estimate_at(black_box(&img), &intr, s.pitch_rad, *level)?;
                tally.time += t.elapsed();
                tally.add(x, &truth, &e);
            }
        }
        println!(
            "\n{} ({n} frames, {:.0} m at {:.1} m/s, pitch {:.0}°; read {:.0} µs a frame)\n",
            scene.name,
            s.end_x_m - s.start_x_m,
            s.speed_mps,
            s.pitch_rad.to_degrees(),
            read.as_secs_f64() * 1e6 / n as f64
        );
        println!("| decimation | time / read | calibrations | spacing error median | p99 | worst | frames over {:.0} % | longer: worst, frames over 5 % | levels used |", budget * 100.0);
        println!("|---|---:|---:|---:|---:|---:|---:|---:|---|");
        // Each row's name and tally: the fixed levels, then `auto` by period.
        let rows: Vec<(String, &Tally)> = fixed
            .iter()
            .map(|(l, _, t)| (format!("fixed {l}"), t))
            .chain(auto.iter().map(|(p, _, t)| {
                let name = if *p == usize::MAX {
                    "auto, first frame only".to_string()
                } else {
                    format!("auto, every {p} frames")
                };
                (name, t)
            }))
            .collect();
        for (name, tally) in &rows {
            tally.row(name, read, budget);
        }
        println!("\nWorst frame of each (x, error, each term's spacing at full resolution → as estimated, m):\n");
        for (name, tally) in &rows {
            if let Some((x, err, terms)) = &tally.worst {
                println!("- {name}: x = {x:.2} m, {:.1} %: {terms}", err * 100.0);
            }
        }
    }
    Ok(())
}
