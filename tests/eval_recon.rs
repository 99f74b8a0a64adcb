//! The two reconstruction renderers on rendered views: a nadir view of flat
//! ground is rebuilt almost exactly by both (the plane at `w_opt` is the
//! ground itself); with a building in view, depth-aided warping beats the
//! single plane, and both beat simply copying the nearer capture.

use alfd::eval::recon::{lightfield, warp, Geometry, View};
use alfd::metrics::psnr;
use alfd::render::{render, survey_camera, RenderOptions};
use alfd::scene::Scene;

fn scene(extra: &str) -> Scene {
    let text = format!(
        r#"name = "t"
[survey]
altitude_m = 40.0
speed_mps = 5.0
hfov_deg = 69.0
width = 96
height = 72
start_x_m = -5.0
end_x_m = 5.0
view_step_m = 0.1
[ground]
texture = {{ colour = [0.4, 0.5, 0.3], contrast = 0.4, cutoff_per_m = 0.6, seed = 1 }}
{extra}
"#
    );
    Scene::parse(&text, "t.toml").unwrap()
}

fn view(sc: &Scene, x: f64) -> View {
    let f = render(
        sc,
        &survey_camera(sc, x, 96, 72),
        &RenderOptions { supersample: 3 },
    );
    View {
        x_m: x,
        lum: f.luminance(),
        depth_m: f.depth_m,
    }
}

fn geometry(sc: &Scene) -> Geometry {
    assert_eq!(sc.survey.pitch_rad, 0.0, "these scenes are nadir");
    Geometry::of_survey(sc, 96, 72)
}

#[test]
fn flat_ground_is_rebuilt_almost_exactly() {
    let sc = scene("");
    let g = geometry(&sc);
    let (a, b, t) = (view(&sc, 0.0), view(&sc, 1.0), view(&sc, 0.5));
    let w = 1.0 / 40.0;
    let pa = psnr(&lightfield(&g, &a, &b, 0.5, w), &t.lum, 1.0);
    let pb = psnr(&warp(&g, &a, &b, 0.5, w), &t.lum, 1.0);
    assert!(pa > 40.0, "light field {pa}");
    assert!(pb > 40.0, "warp {pb}");
}

#[test]
fn warping_beats_one_plane_where_depth_varies() {
    let sc = scene(
        r#"[[box]]
min_m = [-4.0, -4.0, 0.0]
max_m = [4.0, 4.0, 20.0]
texture = { colour = [0.7, 0.6, 0.5], contrast = 0.4, cutoff_per_m = 0.6, seed = 2 }"#,
    );
    let g = geometry(&sc);
    let (a, b, t) = (view(&sc, -1.0), view(&sc, 1.0), view(&sc, 0.0));
    let w = 0.5 * (1.0 / 40.0 + 1.0 / 20.0);
    let pa = psnr(&lightfield(&g, &a, &b, 0.0, w), &t.lum, 1.0);
    let pb = psnr(&warp(&g, &a, &b, 0.0, w), &t.lum, 1.0);
    let copy = psnr(&a.lum, &t.lum, 1.0);
    assert!(pb > pa + 3.0, "warp {pb} vs light field {pa}");
    assert!(pa > copy, "light field {pa} vs nearest copy {copy}");
}
