//! The estimator at 640×480, 848×480 and 1280×720 Z16: the full estimate, each stage,
//! and a baseline measured in the same run that only reads the frame once (the
//! sum of its u16 values). `scripts/bench-ratios.py` prints every figure as a
//! ratio to that baseline, since this machine is shared and noisy.

use alfd::core::closedloop::{pair, unseen_fraction, DepthSnapshot, View};
use alfd::core::estimate::{
    disparity_span_per_m, parallax_in_frame, visibility_step, Estimator, InFrameSpans,
};
use alfd::core::inverse::{fill_grid, fill_grid_counted, percentile_ranks, InvGrid, Selector};
use alfd::core::occlusion::{scan, BoundaryParams};
use alfd::core::plane;
use alfd::core::score;
use alfd::core::visibility::visibility;
use alfd::core::{DepthData, DepthImage, EstimatorParams, Intrinsics};
use alfd::synth::{reference_scenes, to_z16, CameraPose};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use std::time::Duration;

/// The `buildings` frame at `w × h` (Z16, 1 mm), the camera moved `dx_m`
/// along track from the reference pose; and that pose.
fn frame_at(w: usize, h: usize, dx_m: f64) -> (DepthImage, Intrinsics, CameraPose) {
    let (_, world, mut pose) = reference_scenes()
        .into_iter()
        .find(|s| s.0 == "buildings")
        .unwrap();
    pose.position_m[0] += dx_m;
    let intr = Intrinsics::from_hfov_deg(w, h, 69.0, None).unwrap();
    let z = to_z16(&world.render_depth(&pose, &intr), 0.001);
    (
        DepthImage::new(
            w,
            h,
            DepthData::Z16 {
                data: z,
                scale_m: 0.001,
            },
        )
        .unwrap(),
        intr,
        pose,
    )
}

fn frame(w: usize, h: usize) -> (DepthImage, Intrinsics, f64) {
    let (img, intr, pose) = frame_at(w, h, 0.0);
    (img, intr, pose.pitch_rad)
}

/// The closed loop's view of the `buildings` frame with the camera moved
/// `dx_m` along track: its kept depth (about 4800 samples) and pose, in the
/// world frame (x along track, z up; OpenCV camera axes).
fn closed_loop_view(w: usize, h: usize, dx_m: f64) -> View {
    let (img, intr, pose) = frame_at(w, h, dx_m);
    let (s, c) = pose.pitch_rad.sin_cos();
    View {
        depth: DepthSnapshot::kept(&img, &intr),
        // Columns: image x along track, image y across (world −y), optical axis.
        cam_to_ned: glam::DMat3::from_cols(
            glam::DVec3::new(c, 0.0, s),
            glam::DVec3::new(0.0, -1.0, 0.0),
            glam::DVec3::new(s, 0.0, -c),
        ),
        pos_ned_m: glam::DVec3::from(pose.position_m),
    }
}

fn bench(c: &mut Criterion) {
    // 848×480: the RealSense D4xx's native depth mode (docs/performance.md).
    for (w, h) in [(640usize, 480usize), (848, 480), (1280, 720)] {
        let (img, intr, pitch) = frame(w, h);
        let DepthData::Z16 { data, .. } = img.data() else {
            unreachable!()
        };
        let mut g = c.benchmark_group(format!("estimator_{w}x{h}"));
        g.throughput(Throughput::Elements((w * h) as u64));
        g.sample_size(30)
            .warm_up_time(Duration::from_millis(500))
            .measurement_time(Duration::from_secs(2));

        g.bench_function("baseline_sum_u16", |b| {
            b.iter(|| black_box(data).iter().map(|&z| z as u64).sum::<u64>())
        });

        let params = EstimatorParams::default();
        let mut est = Estimator::new(params.clone());
        g.bench_function("estimate_full", |b| {
            b.iter(|| est.estimate_at(black_box(&img), &intr, pitch, 1).unwrap())
        });
        // The sweep on every pixel (`alfd sim`'s setting).
        let mut est_all = Estimator::new(EstimatorParams {
            visibility_samples_max: w * h,
            ..params.clone()
        });
        g.bench_function("estimate_every_pixel", |b| {
            b.iter(|| {
                est_all
                    .estimate_at(black_box(&img), &intr, pitch, 1)
                    .unwrap()
            })
        });
        // A frame of a flight at the defaults (`Estimator::estimate`): the sweep
        // on every pixel of a quarter of the lines (`visibility_interleave`),
        // the other lines' newest sweeps kept (and the shortest interval of
        // the last eight frames held). The same frame again never
        // tightens, so it never sweeps every line (`visibility_refresh`): a
        // flight's frames are `examples/drone_load.rs`'s to time.
        let mut est_flight = Estimator::new(params.clone());
        g.bench_function("estimate_in_flight", |b| {
            b.iter(|| est_flight.estimate(black_box(&img), &intr, pitch).unwrap())
        });
        let no_score = EstimatorParams {
            score: None,
            ..params.clone()
        };
        let mut est_ns = Estimator::new(no_score.clone());
        g.bench_function("estimate_full_no_score", |b| {
            b.iter(|| {
                est_ns
                    .estimate_at(black_box(&img), &intr, pitch, 1)
                    .unwrap()
            })
        });
        for level in [2usize, 4] {
            g.bench_function(format!("estimate_decimation_{level}"), |b| {
                b.iter(|| {
                    est.estimate_at(black_box(&img), &intr, pitch, level)
                        .unwrap()
                })
            });
        }
        // `decimation = "auto"` in steady state: one calibration (every level, full
        // resolution included) per AUTO_RECALIBRATE_FRAMES frames, the chosen level between.
        let mut est_auto = Estimator::new(EstimatorParams {
            decimation: alfd::core::Decimation::auto(),
            ..params.clone()
        });
        g.bench_function("estimate_auto_steady", |b| {
            b.iter(|| est_auto.estimate(black_box(&img), &intr, pitch).unwrap())
        });
        let with_sspa = EstimatorParams {
            with_sspa: true,
            ..params.clone()
        };
        let mut est_sspa = Estimator::new(with_sspa);
        g.bench_function("estimate_full_with_sspa", |b| {
            b.iter(|| {
                est_sspa
                    .estimate_at(black_box(&img), &intr, pitch, 1)
                    .unwrap()
            })
        });

        // Stages.
        let mut grid = InvGrid::default();
        g.bench_function("stage_inverse_depth", |b| {
            b.iter(|| {
                fill_grid(
                    black_box(&img),
                    params.track_axis,
                    1,
                    &params.depth_range,
                    &mut grid,
                )
            })
        });
        fill_grid(&img, params.track_axis, 1, &params.depth_range, &mut grid);
        let mut sel = Selector::default();
        let n = (grid.valid - grid.sky) as u64;
        g.bench_function("stage_percentiles", |b| {
            b.iter(|| sel.select2(black_box(&grid.w), false, percentile_ranks(n, 0.005, 0.995)))
        });
        // What the estimator runs on a Z16 frame: the inverse depth with the
        // Z16 values counted in the same pass, then the percentiles from the count.
        let mut counted = InvGrid::default();
        g.bench_function("stage_inverse_depth_counted", |b| {
            b.iter(|| {
                fill_grid_counted(
                    black_box(&img),
                    params.track_axis,
                    1,
                    &params.depth_range,
                    &mut counted,
                )
            })
        });
        fill_grid_counted(
            &img,
            params.track_axis,
            1,
            &params.depth_range,
            &mut counted,
        );
        g.bench_function("stage_percentiles_from_count", |b| {
            b.iter(|| {
                black_box(&counted).select2(&mut sel, false, percentile_ranks(n, 0.005, 0.995))
            })
        });
        let bp = BoundaryParams {
            tau_abs_per_m: params.tau_abs_per_m,
            tau_rel: params.tau_rel,
            max_gap_px: params.max_gap_px,
            sky_is_scene: params.sky_is_scene,
        };
        g.bench_function("stage_boundaries", |b| {
            b.iter(|| scan(black_box(&grid), &bp, None))
        });
        let geom = intr.track(params.track_axis);
        g.bench_function("stage_sspa_plane_fit", |b| {
            b.iter(|| plane::fit(black_box(&grid), &geom, pitch, 3, 2.5, &mut sel))
        });
        // The quality model's stages (the default model).
        let mut scratch = Vec::new();
        g.bench_function("stage_disparity_span", |b| {
            b.iter(|| {
                disparity_span_per_m(
                    black_box(&grid),
                    &geom,
                    pitch,
                    (0.005, 0.995),
                    0,
                    None,
                    &mut scratch,
                )
            })
        });
        // The term as the estimator runs it: one fill, the span over every
        // sample, then over the samples both captures keep in frame until the
        // spacing settles.
        g.bench_function("stage_parallax_in_frame", |b| {
            b.iter(|| {
                let mut spans = InFrameSpans::new(
                    black_box(&grid),
                    &geom,
                    pitch,
                    (0.005, 0.995),
                    0,
                    &mut scratch,
                );
                let all = spans.span_all()?;
                Some(parallax_in_frame(all, 2.0, |b| spans.span_at(b)))
            })
        });
        let vstep = visibility_step(grid.samples(), 1, params.visibility_samples_max);
        let mut vgrid = InvGrid::default();
        g.bench_function(format!("stage_visibility_grid_step_{vstep}"), |b| {
            b.iter(|| {
                fill_grid(
                    black_box(&img),
                    params.track_axis,
                    vstep,
                    &params.depth_range,
                    &mut vgrid,
                )
            })
        });
        fill_grid(
            &img,
            params.track_axis,
            vstep,
            &params.depth_range,
            &mut vgrid,
        );
        let vp = params.visibility_params();
        g.bench_function(format!("stage_visibility_step_{vstep}"), |b| {
            b.iter(|| visibility(black_box(&vgrid), &geom, pitch, &vp))
        });
        let sp = params.score.clone().unwrap();
        let mut sgrid = InvGrid::default();
        fill_grid(
            &img,
            params.track_axis,
            sp.step_px,
            &params.depth_range,
            &mut sgrid,
        );
        // The closed loop per frame (`[trigger] closed_loop`): keeping the
        // frame, then its two measures against a capture 0.5 m behind.
        let capture = closed_loop_view(w, h, -0.5);
        let (mid, frame_view) = (closed_loop_view(w, h, -0.25), closed_loop_view(w, h, 0.0));
        g.bench_function("closed_loop_keep_frame", |b| {
            b.iter(|| DepthSnapshot::kept(black_box(&img), &intr))
        });
        g.bench_function("closed_loop_parallax_pair", |b| {
            b.iter(|| pair(black_box(&capture), &frame_view))
        });
        g.bench_function("closed_loop_unseen_fraction", |b| {
            b.iter(|| unseen_fraction(black_box(&mid), &capture, &frame_view))
        });
        g.bench_function("stage_score", |b| {
            b.iter(|| {
                score::score(
                    black_box(&sgrid),
                    &geom,
                    pitch,
                    &sp.candidates_rad,
                    0.3,
                    1.0,
                    &bp,
                    sp.min_coverage,
                )
            })
        });
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
