//! The renderer at 640×480 on one thread: time per frame and rays per second
//! (the n×n colour rays of a supersampled frame plus one depth ray per pixel;
//! depth-only frames one ray per pixel), against a baseline in the same run
//! that only generates and sums the colour rays (no scene, one thread), and the
//! reference renderer (the code before binning and the sine table) as "before".
//! The ratio table at the end is what to quote: this machine is shared and noisy.

use alfd::render::{render, render_depth, render_reference, survey_camera, Camera, RenderOptions};
use alfd::scene::Scene;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

const W: usize = 640;
const H: usize = 480;

/// The baseline: the same rays generated and summed, no scene.
fn rays_only(cam: &Camera, ss: usize) -> f64 {
    let mut acc = 0.0;
    for r in 0..H {
        for i in 0..W {
            for sy in 0..ss {
                for sx in 0..ss {
                    let d = cam.ray(
                        i as f64 + (sx as f64 + 0.5) / ss as f64,
                        r as f64 + (sy as f64 + 0.5) / ss as f64,
                    );
                    acc += d[0] + d[1] + d[2];
                }
            }
        }
    }
    acc
}

/// Per bench: rays per frame and the mean time of an iteration in each sample.
type Samples = RefCell<BTreeMap<String, (u64, Vec<f64>)>>;

fn timed<F: FnMut()>(
    g: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    log: &Samples,
    name: &str,
    rays: u64,
    mut f: F,
) {
    g.throughput(Throughput::Elements(rays));
    g.bench_function(name, |b| {
        b.iter_custom(|iters| {
            let t = Instant::now();
            for _ in 0..iters {
                f();
            }
            let e = t.elapsed();
            let mut log = log.borrow_mut();
            let entry = log.entry(name.to_string()).or_insert((rays, Vec::new()));
            entry.1.push(e.as_secs_f64() / iters as f64);
            e
        })
    });
}

fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn bench(c: &mut Criterion) {
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a one-thread pool");
    let log: Samples = RefCell::default();
    let mut g = c.benchmark_group("render_640x480");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(2));
    let load = |name: &str| {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
        let scene = Scene::load(&path).expect("shipped scene");
        let mid = 0.5 * (scene.survey.start_x_m + scene.survey.end_x_m);
        let cam = survey_camera(&scene, mid, W, H);
        (scene, cam)
    };
    let px = (W * H) as u64;
    for name in ["roof", "tree", "edifice", "district"] {
        let (scene, cam) = load(name);
        for ss in [1usize, 3] {
            if name == "roof" {
                timed(
                    &mut g,
                    &log,
                    &format!("baseline_rays_only_ss{ss}"),
                    px * (ss * ss) as u64,
                    || {
                        black_box(rays_only(black_box(&cam), ss));
                    },
                );
            }
            let opts = RenderOptions { supersample: ss };
            timed(
                &mut g,
                &log,
                &format!("{name}_ss{ss}"),
                px * (ss * ss + 1) as u64,
                || {
                    one.install(|| black_box(render(&scene, &cam, &opts)));
                },
            );
        }
    }
    // The renderer by its definition (every primitive per ray, exact sines):
    // the code before binning and the sine table, as "before" in the same run.
    for name in ["roof", "district"] {
        let (scene, cam) = load(name);
        let opts = RenderOptions { supersample: 1 };
        timed(
            &mut g,
            &log,
            &format!("{name}_ss1_reference"),
            px * 2,
            || {
                one.install(|| black_box(render_reference(&scene, &cam, &opts)));
            },
        );
    }
    // What the synthetic depth camera renders 30 times a second.
    let (scene, cam) = load("district");
    timed(&mut g, &log, "district_depth", px, || {
        one.install(|| black_box(render_depth(&scene, &cam)));
    });
    g.finish();

    let log = log.borrow();
    let rate = |(rays, samples): &(u64, Vec<f64>)| *rays as f64 / median(samples);
    let base = |ss: usize| log.get(&format!("baseline_rays_only_ss{ss}")).map(rate);
    println!(
        "\nrender_640x480, one thread, medians; ratio = rays/s over the rays-only baseline's \
         rays/s at the same supersampling (depth: ss1)"
    );
    println!("| bench | ms per frame | rays per frame | Mrays/s | ratio to baseline |");
    println!("|---|---:|---:|---:|---:|");
    for (name, entry) in log.iter() {
        let (rays, samples) = entry;
        let t = median(samples);
        let ss = if name.contains("ss3") { 3 } else { 1 };
        let ratio = match base(ss) {
            Some(b) if !name.starts_with("baseline") => format!("{:.1} %", 100.0 * rate(entry) / b),
            _ => "-".into(),
        };
        println!(
            "| {name} | {:.2} | {rays} | {:.1} | {ratio} |",
            t * 1e3,
            *rays as f64 / t / 1e6
        );
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
