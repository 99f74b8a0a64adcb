//! The renderer at 640×480: time per frame and rays per second (the
//! colour rays of an n×n supersampled frame plus one depth ray per pixel),
//! with a baseline in the same run that only generates the colour rays (no
//! scene, one thread).

use alfd::render::{render, survey_camera, Camera, RenderOptions};
use alfd::scene::Scene;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

/// The baseline: the same rays generated and summed, no scene.
fn rays_only(cam: &Camera, ss: usize) -> f64 {
    let mut acc = 0.0;
    for r in 0..480 {
        for i in 0..640 {
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

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("render_640x480");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(5));
    for name in ["roof", "tree", "edifice"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
        let scene = Scene::load(&path).expect("shipped scene");
        let mid = 0.5 * (scene.survey.start_x_m + scene.survey.end_x_m);
        let cam = survey_camera(&scene, mid, 640, 480);
        for ss in [1usize, 3] {
            let opts = RenderOptions { supersample: ss };
            // Rays per frame: ss² colour rays and one depth ray per pixel.
            g.throughput(Throughput::Elements((640 * 480 * (ss * ss + 1)) as u64));
            g.bench_function(format!("{name}_ss{ss}"), |b| {
                b.iter(|| black_box(render(&scene, &cam, &opts)))
            });
            if name == "roof" {
                g.bench_function(format!("baseline_rays_only_ss{ss}"), |b| {
                    b.iter(|| black_box(rays_only(&cam, ss)))
                });
            }
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
