//! PNG plots of an `alfd sim` run, drawn as `alfd eval` draws its own
//! (plotters into a buffer, the shipped DejaVu Sans, written with `png`).
//! Missing values (`None`, NaN) are gaps, never a panic.

use super::summary::{feasible, min_over, points};
use super::{CaptureAt, DaemonSample, TrackSample};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;
use std::ops::Range;
use std::path::{Path, PathBuf};

const W: u32 = 960;
const H: u32 = 720;
/// Where the chart's plotting area sits inside the image (see `chart`).
const MARGIN: u32 = 10;
const X_LABELS: u32 = 40;
const Y_LABELS: u32 = 64;
const CAPTION: u32 = 34;

const TRUTH: RGBColor = RGBColor(40, 90, 200);
const DAEMON: RGBColor = RGBColor(230, 130, 20);
const CAPTURE: RGBColor = RGBColor(40, 150, 60);
const LATE: RGBColor = RGBColor(200, 40, 40);
const TRACK: RGBColor = RGBColor(150, 150, 150);

/// Above this ratio of largest to smallest, the spacing axis is logarithmic.
const LOG_RANGE: f64 = 20.0;

use crate::eval::plot::save;

/// The unbroken pieces of one line.
type Runs = Vec<Vec<(f64, f64)>>;

/// Finite `(x, y)` runs of a series sorted by `x`: a missing `y` breaks the line.
fn runs(mut pts: Vec<(f64, Option<f64>)>) -> Runs {
    pts.retain(|p| p.0.is_finite());
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out: Runs = Vec::new();
    let mut open = false;
    for (x, y) in pts {
        match y.filter(|y| y.is_finite()) {
            Some(y) if open => out.last_mut().expect("an open run").push((x, y)),
            Some(y) => {
                out.push(vec![(x, y)]);
                open = true;
            }
            None => open = false,
        }
    }
    out
}

/// `lo..hi` of the finite values, widened when empty or flat.
fn extent(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-9 {
        let half = 0.5 * lo.abs().max(1.0);
        return (lo - half, hi + half);
    }
    (lo, hi)
}

/// A chart against along-track metres.
struct AlongPlot {
    title: String,
    y_desc: &'static str,
    /// `(name, colour, runs)`.
    series: Vec<(String, RGBColor, Runs)>,
    /// Capture positions, as ticks at the foot of the chart.
    ticks: Vec<(f64, RGBColor)>,
    /// `(from, to, height, colour)`: capture intervals as horizontal bars.
    intervals: Vec<(f64, f64, f64, RGBColor)>,
    legend_ticks: Option<&'static str>,
    legend_intervals: Option<&'static str>,
}

impl AlongPlot {
    fn ys(&self) -> impl Iterator<Item = f64> + '_ {
        self.series
            .iter()
            .flat_map(|s| s.2.iter().flatten().map(|p| p.1))
            .chain(self.intervals.iter().map(|i| i.2))
    }

    fn xs(&self) -> impl Iterator<Item = f64> + '_ {
        self.series
            .iter()
            .flat_map(|s| s.2.iter().flatten().map(|p| p.0))
            .chain(self.ticks.iter().map(|t| t.0))
    }

    /// Linear from `floor` (or the data's low end), or logarithmic when the
    /// positive values span more than `LOG_RANGE`.
    fn draw(
        &self,
        root: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
        floor: Option<f64>,
        log_if_wide: bool,
    ) -> Result<(), String> {
        let (x0, x1) = extent(self.xs());
        let (lo, hi) = extent(self.ys().filter(|&y| !log_if_wide || y > 0.0));
        if log_if_wide && lo > 0.0 && hi / lo > LOG_RANGE {
            let (lo, hi) = (lo / 1.2, hi * 1.2);
            // The foot of the chart: the lowest 6 % of the axis.
            let tick_top = lo * (hi / lo).powf(0.06);
            return self.chart(root, x0..x1, (lo..hi).log_scale(), (lo, tick_top));
        }
        let lo = floor.map_or(lo, |f| f.min(lo));
        let pad = 0.05 * (hi - lo);
        let (lo, hi) = (lo - pad, hi + pad);
        let tick_top = lo + 0.06 * (hi - lo);
        self.chart(root, x0..x1, lo..hi, (lo, tick_top))
    }

    fn chart<Y>(
        &self,
        root: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
        x: Range<f64>,
        y: Y,
        (tick_lo, tick_hi): (f64, f64),
    ) -> Result<(), String>
    where
        Y: AsRangedCoord<Value = f64>,
        Y::CoordDescType: ValueFormatter<f64>,
    {
        let err = |e: DrawingAreaErrorKind<_>| e.to_string();
        let mut chart = ChartBuilder::on(root)
            .caption(&self.title, ("sans-serif", 20))
            .margin(MARGIN)
            .x_label_area_size(X_LABELS)
            .y_label_area_size(Y_LABELS)
            .build_cartesian_2d(x, y)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("along track (m)")
            .y_desc(self.y_desc)
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(err)?;
        let mut labelled = false;
        if !self.intervals.is_empty() {
            let bars = self
                .intervals
                .iter()
                .map(|&(a, b, h, c)| PathElement::new(vec![(a, h), (b, h)], c.stroke_width(2)));
            let drawn = chart.draw_series(bars).map_err(err)?;
            if let Some(name) = self.legend_intervals {
                labelled = true;
                drawn.label(name).legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(1))
                });
            }
        }
        for (name, colour, series) in &self.series {
            let c = *colour;
            for (k, run) in series.iter().enumerate() {
                let drawn = chart
                    .draw_series(LineSeries::new(run.iter().copied(), c.stroke_width(2)))
                    .map_err(err)?;
                if k == 0 {
                    labelled = true;
                    drawn.label(name.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                    });
                }
            }
        }
        if !self.ticks.is_empty() {
            let ticks = self.ticks.iter().map(|&(x, c)| {
                PathElement::new(vec![(x, tick_lo), (x, tick_hi)], c.stroke_width(2))
            });
            let drawn = chart.draw_series(ticks).map_err(err)?;
            if let Some(name) = self.legend_ticks {
                labelled = true;
                drawn.label(name).legend(|(x, y)| {
                    PathElement::new(vec![(x + 10, y - 6), (x + 10, y + 6)], CAPTURE)
                });
            }
        }
        if labelled {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .label_font(("sans-serif", 14))
                .draw()
                .map_err(err)?;
        }
        Ok(())
    }
}

/// Captures with a finite position, sorted along the track.
fn sorted(captures: &[CaptureAt]) -> Vec<&CaptureAt> {
    let mut c: Vec<&CaptureAt> = captures.iter().filter(|c| c.along_m.is_finite()).collect();
    c.sort_by(|a, b| a.along_m.total_cmp(&b.along_m));
    c
}

fn capture_ticks(caps: &[&CaptureAt]) -> Vec<(f64, RGBColor)> {
    caps.iter()
        .map(|c| (c.along_m, if c.undersampled { LATE } else { CAPTURE }))
        .collect()
}

/// `spacing.png`, `occlusion.png` and `captures.png` in `dir` (created if
/// needed); returns their paths.
pub fn plots(
    truth: &[TrackSample],
    daemon: &[DaemonSample],
    captures: &[CaptureAt],
    dir: &Path,
) -> Result<Vec<PathBuf>, String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let caps = sorted(captures);
    let ticks = capture_ticks(&caps);
    // Truth without an estimate bounds nothing here (the fallback is the
    // summary's business): intervals are judged against the estimates alone.
    let pts = points(truth, f64::INFINITY);
    let intervals: Vec<(f64, f64, f64, RGBColor)> = caps
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0].along_m, w[1].along_m);
            let late = min_over(&pts, a, b).is_some_and(|m| !feasible(b - a, m));
            (a, b, b - a, if late { LATE } else { BLACK })
        })
        .collect();

    let spacing = AlongPlot {
        title: "Permissible spacing along the track, and the capture intervals".into(),
        y_desc: "spacing (m)",
        series: vec![
            (
                "truth (noise-free depth at the true pose)".into(),
                TRUTH,
                runs(truth.iter().map(|t| (t.along_m, t.spacing_m)).collect()),
            ),
            (
                "daemon".into(),
                DAEMON,
                runs(daemon.iter().map(|d| (d.along_m, d.spacing_m)).collect()),
            ),
        ],
        ticks: ticks.clone(),
        intervals,
        legend_ticks: Some("captures (red: flagged under-sampled)"),
        legend_intervals: Some("interval to the next capture (red: above the truth)"),
    };
    let occlusion = AlongPlot {
        title: "Occlusion degree O = ρ·b at the chosen spacing".into(),
        y_desc: "occlusion degree",
        series: vec![
            (
                "truth".into(),
                TRUTH,
                runs(
                    truth
                        .iter()
                        .map(|t| (t.along_m, t.occlusion_degree))
                        .collect(),
                ),
            ),
            (
                "daemon".into(),
                DAEMON,
                runs(
                    daemon
                        .iter()
                        .map(|d| (d.along_m, d.occlusion_degree))
                        .collect(),
                ),
            ),
        ],
        ticks,
        intervals: Vec::new(),
        legend_ticks: Some("captures"),
        legend_intervals: None,
    };

    let mut written = Vec::new();
    let path = dir.join("spacing.png");
    save(&path, |root| spacing.draw(root, None, true))?;
    written.push(path);
    let path = dir.join("occlusion.png");
    save(&path, |root| occlusion.draw(root, Some(0.0), false))?;
    written.push(path);
    let path = dir.join("captures.png");
    save(&path, |root| plan_view(root, truth, &caps))?;
    written.push(path);
    Ok(written)
}

/// Ranges with the same metres per pixel on both axes, so the track's shape
/// is true.
fn equal_aspect(east: (f64, f64), north: (f64, f64)) -> (Range<f64>, Range<f64>) {
    let px_w = f64::from(W - 2 * MARGIN - Y_LABELS);
    let px_h = f64::from(H - 2 * MARGIN - X_LABELS - CAPTION);
    let m_per_px = ((east.1 - east.0) / px_w).max((north.1 - north.0) / px_h) * 1.05;
    let centred = |(lo, hi): (f64, f64), px: f64| {
        let c = 0.5 * (lo + hi);
        (c - 0.5 * m_per_px * px)..(c + 0.5 * m_per_px * px)
    };
    (centred(east, px_w), centred(north, px_h))
}

fn plan_view(
    root: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
    truth: &[TrackSample],
    caps: &[&CaptureAt],
) -> Result<(), String> {
    let err = |e: DrawingAreaErrorKind<_>| e.to_string();
    let finite = |e: f64, n: f64| e.is_finite() && n.is_finite();
    let mut track: Vec<(f64, f64, f64)> = truth
        .iter()
        .filter(|t| t.along_m.is_finite() && finite(t.east_m, t.north_m))
        .map(|t| (t.along_m, t.east_m, t.north_m))
        .collect();
    track.sort_by(|a, b| a.0.total_cmp(&b.0));
    let track: Vec<(f64, f64)> = track.into_iter().map(|(_, e, n)| (e, n)).collect();
    let shots: Vec<(f64, f64, bool)> = caps
        .iter()
        .filter(|c| finite(c.east_m, c.north_m))
        .map(|c| (c.east_m, c.north_m, c.undersampled))
        .collect();
    let east = extent(track.iter().map(|p| p.0).chain(shots.iter().map(|s| s.0)));
    let north = extent(track.iter().map(|p| p.1).chain(shots.iter().map(|s| s.1)));
    let (xr, yr) = equal_aspect(east, north);
    let mut chart = ChartBuilder::on(root)
        .caption(
            format!(
                "Plan view: {} captures, {} flagged under-sampled",
                shots.len(),
                shots.iter().filter(|s| s.2).count()
            ),
            ("sans-serif", 20),
        )
        .margin(MARGIN)
        .x_label_area_size(X_LABELS)
        .y_label_area_size(Y_LABELS)
        .build_cartesian_2d(xr, yr)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("east (m)")
        .y_desc("north (m)")
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(err)?;
    let mut labelled = false;
    if !track.is_empty() {
        labelled = true;
        chart
            .draw_series(LineSeries::new(track, TRACK.stroke_width(2)))
            .map_err(err)?
            .label("true track")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], TRACK.stroke_width(2)));
    }
    for (late, colour, name) in [
        (false, CAPTURE, "capture"),
        (true, LATE, "capture flagged under-sampled"),
    ] {
        let mut these = shots.iter().filter(|s| s.2 == late).peekable();
        if these.peek().is_none() {
            continue;
        }
        labelled = true;
        chart
            .draw_series(these.map(|&(e, n, _)| Circle::new((e, n), 4, colour.filled())))
            .map_err(err)?
            .label(name)
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, colour.filled()));
    }
    if labelled {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(along_m: f64, spacing_m: Option<f64>, degree: Option<f64>) -> TrackSample {
        TrackSample {
            mono_ns: 0,
            along_m,
            north_m: 0.3 * along_m,
            east_m: along_m,
            spacing_m,
            active_bound: None,
            occlusion_degree: degree,
            mmds_m: None,
        }
    }

    fn capture(seq: u64, along_m: f64, undersampled: bool) -> CaptureAt {
        CaptureAt {
            seq,
            mono_ns: 0,
            along_m,
            decided_along_m: along_m,
            north_m: 0.3 * along_m,
            east_m: along_m,
            undersampled,
            rate_limited: false,
            fallback: false,
        }
    }

    /// Decodes a PNG and returns its size.
    fn png_size(path: &Path) -> (u32, u32) {
        let bytes = std::fs::read(path).unwrap();
        assert!(
            bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
            "{}",
            path.display()
        );
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        // Not a blank page: something other than white was drawn.
        assert!(buf.iter().any(|&b| b != 255));
        (info.width, info.height)
    }

    fn check(files: &[PathBuf]) {
        let names: Vec<_> = files
            .iter()
            .map(|p| p.file_name().unwrap().to_str().unwrap())
            .collect();
        assert_eq!(names, ["spacing.png", "occlusion.png", "captures.png"]);
        for f in files {
            assert!(std::fs::metadata(f).unwrap().len() > 0);
            assert_eq!(png_size(f), (W, H));
        }
    }

    #[test]
    fn plots_are_valid_pngs_with_gaps_and_a_wide_range() {
        // Spacing from 0.2 to 30 m (log axis), gaps, NaN, an unsorted sample.
        let mut truth: Vec<_> = (0..200)
            .map(|k| {
                let x = k as f64 * 0.25;
                let s = match k {
                    50..=59 => None,
                    60 => Some(f64::NAN),
                    _ if (20..40).contains(&k) => Some(0.2),
                    _ => Some(30.0),
                };
                sample(x, s, Some(0.01 * (k % 7) as f64))
            })
            .collect();
        truth.swap(3, 4);
        let daemon: Vec<_> = truth
            .iter()
            .map(|t| DaemonSample {
                along_m: t.along_m + 0.1,
                spacing_m: t.spacing_m.map(|s| s * 0.9),
                occlusion_degree: None,
            })
            .collect();
        let captures: Vec<_> = (0..12)
            .map(|k| capture(k + 1, k as f64 * 4.0, k == 5))
            .collect();
        let dir = tempfile::tempdir().unwrap();
        check(&plots(&truth, &daemon, &captures, dir.path()).unwrap());
    }

    #[test]
    fn empty_inputs_still_give_three_pngs() {
        let dir = tempfile::tempdir().unwrap();
        check(&plots(&[], &[], &[], &dir.path().join("nested")).unwrap());
        // One point each, all values missing.
        let truth = [sample(1.0, None, None)];
        let caps = [capture(1, f64::NAN, false), capture(2, 1.0, true)];
        check(&plots(&truth, &[], &caps, dir.path()).unwrap());
    }

    #[test]
    fn runs_break_at_missing_values_and_sort() {
        let r = runs(vec![
            (2.0, Some(2.0)),
            (0.0, Some(0.0)),
            (1.0, Some(1.0)),
            (3.0, None),
            (f64::NAN, Some(9.0)),
            (4.0, Some(f64::INFINITY)),
            (5.0, Some(5.0)),
        ]);
        assert_eq!(
            r,
            vec![vec![(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)], vec![(5.0, 5.0)]]
        );
    }

    #[test]
    fn equal_aspect_keeps_metres_per_pixel() {
        let (x, y) = equal_aspect((0.0, 100.0), (0.0, 0.0));
        let px_w = f64::from(W - 2 * MARGIN - Y_LABELS);
        let px_h = f64::from(H - 2 * MARGIN - X_LABELS - CAPTION);
        let (mx, my) = ((x.end - x.start) / px_w, (y.end - y.start) / px_h);
        assert!((mx - my).abs() < 1e-12 && x.start < 0.0 && x.end > 100.0);
    }
}
