//! Scene files (`alfd::scene::Scene::parse`) on arbitrary UTF-8: a scene or a typed error
//! naming a field and a line inside the text; a scene that validates keeps the documented
//! bounds the renderer relies on.
#![no_main]

use alfd::scene::Scene;
use libfuzzer_sys::fuzz_target;

alfd_fuzz::cap_allocations!();

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Scene::parse(text, "fuzz") {
        Ok(mut scene) => {
            let s = &scene.survey;
            assert!((8..=8192).contains(&s.width) && (8..=8192).contains(&s.height));
            assert!(s.end_x_m > s.start_x_m && s.view_step_m > 0.0);
            let views = s.view_count();
            assert!((1..=100_001).contains(&views), "{views} views");
            assert!(s.view_x_m(views - 1).is_finite());
            scene.scale_textures(0.5);
        }
        Err(e) => {
            let _ = e.to_string();
            if let Some(line) = e.line() {
                assert!(
                    line >= 1 && line <= text.lines().count() + 1,
                    "line {line} of a {}-line text",
                    text.lines().count()
                );
            }
        }
    }
});
