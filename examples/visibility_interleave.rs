//! What spreading the visibility sweep over frames (`[estimator]
//! visibility_interleave`) costs in error and buys in time, against thinning it
//! (`visibility_samples_max`): along each scene's survey line, 640×480 Z16 depth
//! every 1/30 s at the scene's speed (the daemon's 30 fps), the daemon's
//! estimator (`[quality] profile = "lightfield"`, as `alfd sim`), each setting
//! fed the frames in order, against the same frame's estimate with the sweep
//! over every pixel. Per setting: the estimator's time per frame as a ratio to
//! reading the frame once (the sum of its u16 values, timed on the same frames in
//! the same run), and how much longer than the reference (the unsafe side) the
//! permissible and the views-per-point spacings came out
//! (`docs/error-vs-runtime.md`):
//! `cargo run --release --example visibility_interleave [-- scenes/district.toml ...]`
//! (default: `district`, `alfd sim`'s scene, and the eight evaluation scenes).

#[path = "common/survey.rs"]
mod survey;

use alfd::core::estimate::{relative_error, relative_excess};
use alfd::core::{Estimate, Estimator, EstimatorParams};
use alfd::scene::Scene;
use std::hint::black_box;
use std::time::{Duration, Instant};

const W: usize = 640;
const H: usize = 480;

/// `(name, visibility_samples_max, visibility_interleave, visibility_refresh)`.
const SETTINGS: [(&str, usize, usize, bool); 8] = [
    (
        "thinned to 80,000, every frame (the flight default until 2026-11-27)",
        80_000,
        1,
        false,
    ),
    ("thinned to 40,000", 40_000, 1, false),
    ("every pixel, interleave 2", usize::MAX, 2, false),
    ("every pixel, interleave 2, refreshing", usize::MAX, 2, true),
    ("every pixel, interleave 4", usize::MAX, 4, false),
    (
        "every pixel, interleave 4, refreshing (the flight default)",
        usize::MAX,
        4,
        true,
    ),
    ("every pixel, interleave 8", usize::MAX, 8, false),
    ("every pixel, interleave 8, refreshing", usize::MAX, 8, true),
];

#[derive(Default)]
struct Tally {
    time: Duration,
    errors: Vec<f64>,
    /// Largest excess of the permissible and of the views spacing, and the
    /// frames where the permissible one is over 5 % too long.
    long: f64,
    long_views: f64,
    long_frames: usize,
    /// The worst frame: position, excess, the views spacing reference → setting.
    worst: Option<(f64, f64, String)>,
    /// Frames that swept every line, the first one included.
    every_line: usize,
}

impl Tally {
    fn add(&mut self, x_m: f64, reference: &Estimate, e: &Estimate) {
        let (a, b) = (&reference.spacing, &e.spacing);
        self.every_line += e.visibility.is_some_and(|v| v.interleave == 1) as usize;
        self.errors
            .push(relative_error(b.permissible_m, a.permissible_m));
        let excess = relative_excess(b.permissible_m, a.permissible_m);
        self.long_frames += (excess > 0.05) as usize;
        self.long_views = self.long_views.max(relative_excess(b.views_m, a.views_m));
        if excess > self.long || self.worst.is_none() {
            let f = |x: Option<f64>| x.map_or("–".into(), |v| format!("{v:.3}"));
            self.worst = Some((
                x_m,
                excess,
                format!(
                    "permissible {} → {}, views {} → {}",
                    f(a.permissible_m),
                    f(b.permissible_m),
                    f(a.views_m),
                    f(b.views_m)
                ),
            ));
        }
        self.long = self.long.max(excess);
    }

    fn row(&self, name: &str, read: Duration, reference: Duration) {
        let mut e = self.errors.clone();
        e.sort_by(f64::total_cmp);
        let at = |q: f64| e[((e.len() - 1) as f64 * q).round() as usize];
        println!(
            "| {name} | {:.1}× | {:.2}× | {} | {:.2} % | {:.2} % | {:.1} % | {} of {} | {:.1} % |",
            self.time.as_secs_f64() / read.as_secs_f64(),
            reference.as_secs_f64() / self.time.as_secs_f64(),
            self.every_line,
            100.0 * at(0.5),
            100.0 * at(1.0),
            100.0 * self.long,
            self.long_frames,
            e.len(),
            100.0 * self.long_views,
        );
    }
}

fn main() -> anyhow::Result<()> {
    let paths = survey::scene_paths();
    let base: EstimatorParams =
        alfd::config::Config::from_text("[quality]\nprofile = \"lightfield\"\n", "sim")?.estimator;
    for path in &paths {
        let scene = Scene::load(path)?;
        let s = scene.survey.clone();
        let sensor = survey::sensor(&scene);
        let n = survey::positions_m(&scene).count();
        let mut reference = Estimator::new(EstimatorParams {
            visibility_samples_max: usize::MAX,
            ..base.clone()
        });
        let mut runs: Vec<(&str, Estimator, Tally)> = SETTINGS
            .iter()
            .map(|&(name, samples, interleave, refresh)| {
                let params = EstimatorParams {
                    visibility_samples_max: samples,
                    visibility_interleave: interleave,
                    visibility_refresh: refresh,
                    ..base.clone()
                };
                params.validate().expect("a valid setting");
                (name, Estimator::new(params), Tally::default())
            })
            .collect();
        let (mut read, mut reference_time) = (Duration::ZERO, Duration::ZERO);
        for x in survey::positions_m(&scene) {
            let (img, intr) = survey::z16_at(&scene, x, (W, H), &sensor)?;
            read += survey::read_time(&img);
            let t = Instant::now();
            let truth = reference.estimate_at(black_box(&img), &intr, s.pitch_rad, 1)?;
            reference_time += t.elapsed();
            for (_, est, tally) in runs.iter_mut() {
                let t = Instant::now();
                let (e, _) = est.estimate(black_box(&img), &intr, s.pitch_rad)?;
                tally.time += t.elapsed();
                tally.add(x, &truth, &e);
            }
        }
        println!(
            "\n{} ({n} frames, {:.0} m at {:.1} m/s, pitch {:.0}°; read {:.0} µs, every pixel {:.2} ms a frame)\n",
            scene.name,
            s.end_x_m - s.start_x_m,
            s.speed_mps,
            s.pitch_rad.to_degrees(),
            read.as_secs_f64() * 1e6 / n as f64,
            reference_time.as_secs_f64() * 1e3 / n as f64,
        );
        println!("| visibility sweep | time / read | speed-up vs every pixel | frames sweeping every line | spacing error median | worst | longer: worst | frames over 5 % longer | views spacing longer: worst |");
        println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");
        for (name, _, tally) in &runs {
            tally.row(name, read, reference_time);
        }
        println!("\nWorst frame of each (x, longer by, reference → setting, m):\n");
        for (name, _, tally) in &runs {
            if let Some((x, excess, terms)) = &tally.worst {
                println!("- {name}: x = {x:.2} m, {:.1} %: {terms}", excess * 100.0);
            }
        }
    }
    Ok(())
}
