//! The scene file format: every shipped scene parses; bad files get an error
//! naming the field and its line.

use alfd::scene::{Scene, SceneError};
use std::path::Path;

const GOOD: &str = r#"name = "t"

[survey]
altitude_m = 40.0
speed_mps = 5.0
pitch_deg = 10.0
hfov_deg = 69.0
width = 64
height = 48
start_x_m = -5.0
end_x_m = 5.0
view_step_m = 0.1

[ground]
texture = { colour = [0.4, 0.5, 0.3], contrast = 0.4, cutoff_per_m = 2.0, seed = 1 }

[[box]]
min_m = [-2.0, -2.0, 0.0]
max_m = [2.0, 2.0, 10.0]
texture = { colour = [0.7, 0.7, 0.7] }

[[ellipsoid]]
centre_m = [5.0, 0.0, 8.0]
radii_m = [2.0, 2.0, 3.0]
texture = { colour = [0.2, 0.4, 0.1], contrast = 0.5 }
"#;

fn err(text: &str) -> SceneError {
    Scene::parse(text, "t.toml").expect_err("must be rejected")
}

#[test]
fn shipped_scenes_parse() {
    for name in alfd::eval::SCENES {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
        let s = Scene::load(&p).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.name, name);
        assert!(s.survey.view_count() > 100, "{name}");
    }
}

#[test]
fn good_scene_parses_with_defaults() {
    let s = Scene::parse(GOOD, "t.toml").unwrap();
    assert_eq!(s.boxes.len(), 1);
    assert_eq!(s.ellipsoids.len(), 1);
    assert_eq!(s.survey.view_count(), 101);
    assert!((s.survey.pitch_rad - 10f64.to_radians()).abs() < 1e-12);
    // The roof falls back to the wall texture.
    assert_eq!(s.boxes[0].roof, s.boxes[0].texture);
    assert_eq!(s.ground.as_ref().unwrap().z_m, 0.0);
}

#[test]
fn unknown_field_is_named_with_its_line() {
    let e = err(&GOOD.replace("speed_mps = 5.0", "speed_mps = 5.0\nsped = 3"));
    let m = e.to_string();
    assert!(m.contains("sped"), "{m}");
    assert_eq!(e.line(), Some(6), "{m}");
    assert_eq!(e.field(), Some("survey.sped"), "{m}");
}

#[test]
fn wrong_type_names_the_field_and_line() {
    let e = err(&GOOD.replace("altitude_m = 40.0", "altitude_m = \"high\""));
    assert_eq!(e.field(), Some("survey.altitude_m"), "{e}");
    assert_eq!(e.line(), Some(4), "{e}");
}

#[test]
fn missing_field_is_named() {
    let e = err(&GOOD.replace("hfov_deg = 69.0\n", ""));
    assert_eq!(e.field(), Some("survey.hfov_deg"), "{e}");
    assert!(e.line().is_some(), "{e}");
}

#[test]
fn out_of_range_values_name_the_field_and_line() {
    let e = err(&GOOD.replace("radii_m = [2.0, 2.0, 3.0]", "radii_m = [2.0, -1.0, 3.0]"));
    assert_eq!(e.field(), Some("ellipsoid[0].radii_m"), "{e}");
    assert_eq!(e.line(), Some(24), "{e}");

    let e = err(&GOOD.replace("max_m = [2.0, 2.0, 10.0]", "max_m = [2.0, -3.0, 10.0]"));
    assert_eq!(e.field(), Some("box[0].max_m"), "{e}");
    assert_eq!(e.line(), Some(19), "{e}");

    let e = err(&GOOD.replace("hfov_deg = 69.0", "hfov_deg = 190.0"));
    assert_eq!(e.field(), Some("survey.hfov_deg"), "{e}");
    assert_eq!(e.line(), Some(7), "{e}");

    let e = err(&GOOD.replace("end_x_m = 5.0", "end_x_m = -6.0"));
    assert_eq!(e.field(), Some("survey.end_x_m"), "{e}");
    assert_eq!(e.line(), Some(11), "{e}");

    let e = err(&GOOD.replace("contrast = 0.4", "contrast = 1.4"));
    assert_eq!(e.field(), Some("ground.texture"), "{e}");
    assert_eq!(e.line(), Some(15), "{e}");
    assert!(e.to_string().contains("contrast"), "{e}");
}

#[test]
fn second_box_is_indexed() {
    let text = format!(
        "{GOOD}\n[[box]]\nmin_m = [0.0, 0.0, 0.0]\nmax_m = [1.0, 1.0, 0.0]\ntexture = {{ colour = [0.5, 0.5, 0.5] }}\n"
    );
    let e = err(&text);
    assert_eq!(e.field(), Some("box[1].max_m"), "{e}");
    assert_eq!(e.line(), Some(29), "{e}");
}

#[test]
fn unknown_table_is_rejected() {
    let e = err(&format!("{GOOD}\n[[cone]]\nheight = 3\n"));
    assert!(e.to_string().contains("cone"), "{e}");
}

#[test]
fn missing_file_is_a_read_error() {
    let e = Scene::load(Path::new("/nonexistent/scene.toml")).unwrap_err();
    assert!(matches!(e, SceneError::Read { .. }), "{e}");
}
