//! PNG plots of `alfd eval` (plotters into a buffer, written with `png`; text
//! in the shipped DejaVu Sans, so no system font is needed).

use super::{SceneResult, METHODS};
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

const W: u32 = 960;
const H: u32 = 720;
const COLOURS: [RGBColor; 4] = [
    RGBColor(200, 40, 40),
    RGBColor(40, 90, 200),
    RGBColor(40, 150, 60),
    RGBColor(120, 120, 120),
];

static FONT: Once = Once::new();

fn font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
        // A font that fails to load only costs the labels.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes);
    });
}

type Series = Vec<(String, RGBColor, Vec<(f64, f64)>)>;

fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    y_label: &str,
    x_range: (f64, f64),
    series: &Series,
) -> Result<(), String> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (_, _, pts) in series {
        for &(_, y) in pts {
            if y.is_finite() {
                lo = lo.min(y);
                hi = hi.max(y);
            }
        }
    }
    if !lo.is_finite() {
        lo = 0.0;
        hi = 1.0;
    }
    if hi - lo < 1e-9 {
        hi = lo + 1.0;
    }
    let pad = 0.05 * (hi - lo);
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(60)
        .build_cartesian_2d(x_range.0..x_range.1, (lo - pad)..(hi + pad))
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("x along track (m)")
        .y_desc(y_label)
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|e| e.to_string())?;
    for (name, colour, pts) in series {
        let c = *colour;
        chart
            .draw_series(LineSeries::new(
                pts.iter().copied().filter(|p| p.1.is_finite()),
                c.stroke_width(2),
            ))
            .map_err(|e| e.to_string())?
            .label(name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(|e| e.to_string())?;
    Ok(())
}

/// Draws into a 960×720 white bitmap with the shipped font and writes it as
/// PNG (shared by `alfd eval` and `alfd sim`'s plots).
pub(crate) fn save(
    path: &Path,
    draw: impl FnOnce(&DrawingArea<BitMapBackend, plotters::coord::Shift>) -> Result<(), String>,
) -> Result<(), String> {
    font();
    let mut buf = vec![255u8; (W * H * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (W, H)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        draw(&root)?;
        root.present().map_err(|e| e.to_string())?;
    }
    crate::render::write_png(path, W as usize, H as usize, &buf)
        .map_err(|e| format!("{}: {e}", path.display()))
}

/// `<scene>_spacing.png` (spacing and occlusion degree along the track per
/// method) and `<scene>_psnr.png` (PSNR of each in-between view, both renderers).
pub fn scene_plots(r: &SceneResult, dir: &Path) -> Result<(), String> {
    let xr = (r.xs[0], *r.xs.last().unwrap_or(&(r.xs[0] + 1.0)));
    // One series per method of a value read off each view's estimates.
    let per_method = |value: &dyn Fn(&_, usize) -> f64| -> Series {
        METHODS
            .iter()
            .enumerate()
            .map(|(m, model)| {
                (
                    model.as_str().to_string(),
                    COLOURS[m],
                    r.xs.iter()
                        .zip(&r.estimates)
                        .map(|(&x, e)| (x, value(e, m)))
                        .collect(),
                )
            })
            .collect()
    };
    let spacing = per_method(&|e, m| e.chosen_m[m].unwrap_or(f64::NAN));
    let degree = per_method(&|e, m| e.density_per_m * e.chosen_m[m].unwrap_or(f64::NAN));
    save(&dir.join(format!("{}_spacing.png", r.name)), |root| {
        let parts = root.split_evenly((2, 1));
        panel(
            &parts[0],
            &format!("{}: chosen spacing per method", r.name),
            "spacing (m)",
            xr,
            &spacing,
        )?;
        panel(
            &parts[1],
            &format!("{}: occlusion degree O = ρ·b at that spacing", r.name),
            "O",
            xr,
            &degree,
        )
    })?;
    let psnr = |k: usize| -> Series {
        METHODS
            .iter()
            .enumerate()
            .map(|(m, model)| {
                (
                    format!(
                        "{} ({} captures)",
                        model.as_str(),
                        r.runs[m][0].captures.len()
                    ),
                    COLOURS[m],
                    r.xs.iter()
                        .zip(&r.runs[m][0].scores)
                        .filter_map(|(&x, s)| s.map(|s| (x, s.psnr_db[k])))
                        .collect(),
                )
            })
            .collect()
    };
    save(&dir.join(format!("{}_psnr.png", r.name)), |root| {
        let parts = root.split_evenly((2, 1));
        panel(
            &parts[0],
            &format!("{}: PSNR, light field at w_opt (own spacing)", r.name),
            "PSNR (dB)",
            xr,
            &psnr(0),
        )?;
        panel(
            &parts[1],
            &format!("{}: PSNR, depth-aided warping (own spacing)", r.name),
            "PSNR (dB)",
            xr,
            &psnr(1),
        )
    })
}
