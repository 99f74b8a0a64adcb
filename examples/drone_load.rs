//! The estimator's load on a drone at the flight's defaults, along a survey
//! line rather than one frame repeated (the bench's `buildings` frame never
//! changes, so it never pays for `visibility_refresh`): at 640×480 and 848×480
//! Z16, 30 fps at the scene's speed, decimation 1, 2 and 4, the daemon's
//! estimator on one thread (`[quality] profile = "lightfield"`, every other
//! `[estimator]` key at its default) fed the frames in order. Per setting: the
//! time per frame (mean and worst), the share of one core here at 30 fps, the
//! same scaled to the boards by `docs/performance.md`'s single-core ratios
//! (estimates, not measurements), and the error against the same frame swept
//! at every pixel of every line (the permissible spacing longer than that,
//! the unsafe side):
//! `cargo run --release --example drone_load [-- scenes/district.toml ...]`
//! (default: `district`, `alfd sim`'s scene, and the eight evaluation scenes).

#[path = "common/survey.rs"]
mod survey;

use alfd::core::estimate::relative_excess;
use alfd::core::{Decimation, Estimator, EstimatorParams};
use alfd::scene::Scene;
use std::hint::black_box;
use std::time::{Duration, Instant};

const SIZES: [(usize, usize); 2] = [(640, 480), (848, 480)];
const DECIMATIONS: [usize; 3] = [1, 2, 4];
/// `docs/performance.md`, "On the drone": a core of each board against one here.
const BOARDS: [(&str, f64); 3] = [("Pi 4", 8.0), ("Pi 5", 3.0), ("Orin Nano", 3.5)];

struct Run {
    decimation: usize,
    est: Estimator,
    times: Vec<Duration>,
    every_line: usize,
    long_frames: usize,
    longest: f64,
}

fn main() -> anyhow::Result<()> {
    let base: EstimatorParams =
        alfd::config::Config::from_text("[quality]\nprofile = \"lightfield\"\n", "sim")?.estimator;
    for path in &survey::scene_paths() {
        let scene = Scene::load(path)?;
        let s = scene.survey.clone();
        let sensor = survey::sensor(&scene);
        let n = survey::positions_m(&scene).count();
        for (w, h) in SIZES {
            let mut reference = Estimator::new(EstimatorParams {
                visibility_samples_max: usize::MAX,
                visibility_interleave: 1,
                ..base.clone()
            });
            let mut runs: Vec<Run> = DECIMATIONS
                .iter()
                .map(|&d| {
                    let p = EstimatorParams {
                        decimation: Decimation::Fixed(d),
                        ..base.clone()
                    };
                    p.validate().expect("a valid setting");
                    Run {
                        decimation: d,
                        est: Estimator::new(p),
                        times: Vec::with_capacity(n),
                        every_line: 0,
                        long_frames: 0,
                        longest: 0.0,
                    }
                })
                .collect();
            let mut read = Duration::ZERO;
            for x in survey::positions_m(&scene) {
                let (img, intr) = survey::z16_at(&scene, x, (w, h), &sensor)?;
                read += survey::read_time(&img);
                let truth = reference.estimate_at(&img, &intr, s.pitch_rad, 1)?;
                for r in runs.iter_mut() {
                    let t = Instant::now();
                    let (e, _) = r.est.estimate(black_box(&img), &intr, s.pitch_rad)?;
                    r.times.push(t.elapsed());
                    r.every_line += e.visibility.is_some_and(|v| v.interleave == 1) as usize;
                    let excess =
                        relative_excess(e.spacing.permissible_m, truth.spacing.permissible_m);
                    r.long_frames += (excess > 0.05) as usize;
                    r.longest = r.longest.max(excess);
                }
            }
            let read_ms = read.as_secs_f64() * 1e3 / n as f64;
            println!(
                "\n{} at {w}×{h} ({n} frames, {:.1} m/s; read {:.0} µs a frame)\n",
                scene.name,
                s.speed_mps,
                read_ms * 1e3
            );
            print!("| decimation | ms per frame: mean / worst | × the read (mean) | frames sweeping every line | % of one core here at 30 fps |");
            for (board, _) in BOARDS {
                print!(" {board}: % of a core (worst frame, ms) |");
            }
            println!(" permissible longer than every pixel: frames over 5 %, worst |");
            println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
            for r in &runs {
                let mean_ms =
                    r.times.iter().map(Duration::as_secs_f64).sum::<f64>() * 1e3 / n as f64;
                let worst_ms = r
                    .times
                    .iter()
                    .map(Duration::as_secs_f64)
                    .fold(0.0, f64::max)
                    * 1e3;
                let share = |ms: f64| ms * 30.0 / 10.0;
                print!(
                    "| {} | {mean_ms:.2} / {worst_ms:.1} | {:.1}× | {} | {:.1} % |",
                    r.decimation,
                    mean_ms / read_ms,
                    r.every_line,
                    share(mean_ms)
                );
                for (_, ratio) in BOARDS {
                    print!(
                        " {:.0} % ({:.0}) |",
                        share(mean_ms * ratio),
                        worst_ms * ratio
                    );
                }
                println!(" {} of {n}, {:.1} % |", r.long_frames, 100.0 * r.longest);
            }
        }
    }
    Ok(())
}
