//! The daemon's captures against the truth track: violations, the ideal count
//! and the fixed-distance baseline, as defined in the module above.

use super::{CaptureAt, TrackSample};
use crate::capture::{CaptureRecord, QualityTargets};
use serde::Serialize;
use std::collections::BTreeMap;

/// Relative tolerance of "within the spacing" (the same test everywhere).
const REL_TOL: f64 = 1e-6;
/// Positions closer than this are the same place (rounding of `along_m`).
const EPS_M: f64 = 1e-6;

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SpacingRange {
    pub min_m: f64,
    pub median_m: f64,
    pub max_m: f64,
}

/// Why an interval longer than the truth's spacing was so (the module doc's classes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ViolationClass {
    Unavoidable,
    FirstSight,
    Avoidable,
}

/// One interval between consecutive captures longer than the truth's spacing over it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Violation {
    /// The captures that bound it (manifest `seq`).
    pub from_seq: u64,
    pub to_seq: u64,
    /// Where along the truth track, metres.
    pub from_along_m: f64,
    pub to_along_m: f64,
    /// The smallest truth spacing in force over it, metres.
    pub truth_spacing_m: f64,
    /// `(to − from) / truth_spacing_m`.
    pub ratio: f64,
    pub class: ViolationClass,
}

/// Avoidable violations the text summary lists (all are in `summary.json`).
const LISTED: usize = 5;

/// The acceptance figures of one run (`summary.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    pub captures: usize,
    pub truth_samples: usize,
    /// `along_m` span of the truth track.
    pub track_length_m: f64,
    /// From the first capture to the last, metres.
    pub stretch_m: f64,
    pub ideal_captures: Option<usize>,
    /// Steps of the ideal sequence to the next sample that exceed the spacing.
    pub ideal_unavoidable: usize,
    /// `captures / ideal_captures`.
    pub ratio_to_ideal: Option<f64>,
    pub violations: usize,
    pub unavoidable_violations: usize,
    /// Violations only the closing frame's spacing makes (module doc).
    pub first_sight_violations: usize,
    pub avoidable_violations: usize,
    /// Largest `interval / minimum spacing in force` among the violations.
    pub worst_excess_ratio: Option<f64>,
    pub worst_avoidable_excess_ratio: Option<f64>,
    /// Every violation, in track order: where, by how much, of which class.
    pub violation_list: Vec<Violation>,
    /// Largest `interval / minimum spacing in force` over all intervals.
    pub max_interval_ratio: Option<f64>,
    /// Intervals with no truth at all to judge them by (no truth samples).
    pub unjudged_intervals: usize,
    /// Captures the daemon flagged.
    pub undersampled: usize,
    pub rate_limited: usize,
    pub fallback: usize,
    /// Truth samples in the stretch without an estimate (the fallback in force).
    pub fallback_samples: usize,
    /// Spacing in force over the truth samples of the stretch (the whole
    /// track when there are no captures).
    pub spacing_m: Option<SpacingRange>,
    pub fixed_spacing_m: Option<f64>,
    pub fixed_captures: Option<usize>,
    /// `captures / fixed_captures`.
    pub data_ratio: Option<f64>,
    pub fallback_spacing_m: f64,
    pub step_limit_m: f64,
    /// Captures per bound that set their spacing (`spacing.active_bound`).
    pub captures_by_bound: BTreeMap<String, usize>,
    /// Captures whose estimate used each term (`terms`).
    pub captures_by_term: BTreeMap<String, usize>,
    /// The quality targets in force (the quality model only).
    pub quality_targets: Option<QualityTargets>,
    /// What the truth judged a flight of another model by (the quality
    /// model's targets), in words; `None` for a quality flight, whose
    /// `targets` say it.
    pub judged_by: Option<String>,
}

/// One opportunity: a distinct position and the smallest spacing in force there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Point {
    along_m: f64,
    spacing_m: f64,
}

fn in_force(spacing_m: Option<f64>, fallback_m: f64) -> f64 {
    match spacing_m {
        Some(s) if s.is_finite() && s > 0.0 => s,
        _ => fallback_m,
    }
}

pub(super) fn feasible(interval_m: f64, spacing_m: f64) -> bool {
    interval_m <= spacing_m * (1.0 + REL_TOL)
}

/// Truth samples with a finite position, sorted, equal positions merged.
pub(super) fn points(truth: &[TrackSample], fallback_m: f64) -> Vec<Point> {
    let mut v: Vec<Point> = truth
        .iter()
        .filter(|t| t.along_m.is_finite())
        .map(|t| Point {
            along_m: t.along_m,
            spacing_m: in_force(t.spacing_m, fallback_m),
        })
        .collect();
    v.sort_by(|a, b| a.along_m.total_cmp(&b.along_m));
    let mut out: Vec<Point> = Vec::with_capacity(v.len());
    for p in v {
        match out.last_mut() {
            Some(q) if q.along_m == p.along_m => q.spacing_m = q.spacing_m.min(p.spacing_m),
            _ => out.push(p),
        }
    }
    out
}

/// Index range of the points with `along ∈ [a, b]` (widened by `EPS_M`).
fn within(points: &[Point], a: f64, b: f64) -> std::ops::Range<usize> {
    let lo = points.partition_point(|p| p.along_m < a - EPS_M);
    let hi = points.partition_point(|p| p.along_m <= b + EPS_M);
    lo..hi.max(lo)
}

/// Minimum spacing in force over `[a, b]`; the nearest point on each side
/// when none is inside; `None` without points.
pub(super) fn min_over(points: &[Point], a: f64, b: f64) -> Option<f64> {
    let r = within(points, a, b);
    let range = if r.is_empty() {
        r.start.saturating_sub(1)..(r.end + 1).min(points.len())
    } else {
        r
    };
    points[range].iter().map(|p| p.spacing_m).reduce(f64::min)
}

/// Number of points strictly between `a` and `b` (by more than `EPS_M`).
fn strictly_between(points: &[Point], a: f64, b: f64) -> usize {
    let lo = points.partition_point(|p| p.along_m <= a + EPS_M);
    let hi = points.partition_point(|p| p.along_m < b - EPS_M);
    hi.saturating_sub(lo)
}

/// Index of the point nearest `x` (the earlier on a tie).
fn nearest(points: &[Point], x: f64) -> Option<usize> {
    let i = points.partition_point(|p| p.along_m < x);
    match (i.checked_sub(1), (i < points.len()).then_some(i)) {
        (Some(a), Some(b)) => Some(if x - points[a].along_m <= points[b].along_m - x {
            a
        } else {
            b
        }),
        (Some(a), None) => Some(a),
        (None, b) => b,
    }
}

/// The fewest captures from point `s` to point `e` (both captured), every
/// interval feasible except a forced step to the very next point; returns
/// `(captures, forced steps)`.
///
/// Greedy is optimal. Call an interval `[i, j]` *allowed* when it is feasible
/// or `j = i + 1`. Allowed intervals are closed under shrinking: for
/// `i ≤ i' < j' ≤ j`, `along_j' − along_i' ≤ along_j − along_i` and the minimum
/// over `[i', j']` is at least the minimum over `[i, j]`, so a feasible interval
/// has only feasible sub-intervals (and the sub-intervals of `[i, i+1]` are
/// itself). Hence, for a fixed `i`, feasibility fails for good once it fails
/// as `j` grows (the scan below may stop there), and greedy stays ahead: let
/// `g_t` be its t-th capture and `o_t` any allowed sequence's, `g_0 = o_0 = s`.
/// If `g_t ≥ o_t`, either `o_{t+1} ≤ g_t < g_{t+1}`, or `[g_t, o_{t+1}]` lies
/// inside the allowed `[o_t, o_{t+1}]` and is allowed, so greedy, taking the
/// farthest allowed point, reaches `g_{t+1} ≥ o_{t+1}`. So greedy reaches `e` in
/// no more steps than any allowed sequence.
fn ideal(points: &[Point], s: usize, e: usize) -> (usize, usize) {
    let (mut i, mut count, mut forced) = (s, 1, 0);
    while i < e {
        let mut m = points[i].spacing_m;
        let mut far = None;
        for (j, p) in points.iter().enumerate().take(e + 1).skip(i + 1) {
            m = m.min(p.spacing_m);
            if !feasible(p.along_m - points[i].along_m, m) {
                break;
            }
            far = Some(j);
        }
        i = match far {
            Some(j) => j,
            None => {
                forced += 1;
                i + 1
            }
        };
        count += 1;
    }
    (count, forced)
}

fn median(mut v: Vec<f64>) -> Option<SpacingRange> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let median_m = if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    };
    Some(SpacingRange {
        min_m: v[0],
        median_m,
        max_m: v[n - 1],
    })
}

fn max_opt(a: Option<f64>, b: f64) -> Option<f64> {
    Some(a.map_or(b, |a| a.max(b)))
}

/// Judges `captures` against the truth track (definitions in the module doc).
/// A `fallback_spacing_m` that is not a finite positive number bounds nothing.
pub fn summarize(
    truth: &[TrackSample],
    captures: &[CaptureAt],
    fallback_spacing_m: f64,
    step_limit_m: f64,
) -> Summary {
    let fallback_m = if fallback_spacing_m.is_finite() && fallback_spacing_m > 0.0 {
        fallback_spacing_m
    } else {
        f64::INFINITY
    };
    let pts = points(truth, fallback_m);
    let mut caps: Vec<&CaptureAt> = captures.iter().filter(|c| c.along_m.is_finite()).collect();
    caps.sort_by(|a, b| a.along_m.total_cmp(&b.along_m).then(a.seq.cmp(&b.seq)));

    let mut s = Summary {
        captures: captures.len(),
        truth_samples: truth.len(),
        track_length_m: match (pts.first(), pts.last()) {
            (Some(a), Some(b)) => b.along_m - a.along_m,
            _ => 0.0,
        },
        stretch_m: 0.0,
        ideal_captures: None,
        ideal_unavoidable: 0,
        ratio_to_ideal: None,
        violations: 0,
        unavoidable_violations: 0,
        first_sight_violations: 0,
        avoidable_violations: 0,
        worst_excess_ratio: None,
        worst_avoidable_excess_ratio: None,
        violation_list: Vec::new(),
        max_interval_ratio: None,
        unjudged_intervals: 0,
        undersampled: captures.iter().filter(|c| c.undersampled).count(),
        rate_limited: captures.iter().filter(|c| c.rate_limited).count(),
        fallback: captures.iter().filter(|c| c.fallback).count(),
        fallback_samples: 0,
        spacing_m: None,
        fixed_spacing_m: None,
        fixed_captures: None,
        data_ratio: None,
        fallback_spacing_m,
        step_limit_m,
        captures_by_bound: BTreeMap::new(),
        captures_by_term: BTreeMap::new(),
        quality_targets: None,
        judged_by: None,
    };

    for w in caps.windows(2) {
        let (a, b) = (w[0].along_m, w[1].along_m);
        let d = b - a;
        let Some(m) = min_over(&pts, a, b) else {
            s.unjudged_intervals += 1;
            continue;
        };
        let ratio = d / m;
        s.max_interval_ratio = max_opt(s.max_interval_ratio, ratio);
        if feasible(d, m) {
            continue;
        }
        s.violations += 1;
        s.worst_excess_ratio = max_opt(s.worst_excess_ratio, ratio);
        // The interval's samples before the last opportunity step: what was seen before
        // the frame that closed it (none: nothing of it was, as when a camera's picture
        // comes a way after the frame that commanded it).
        let cut_m = w[1].decided_along_m.min(b) - step_limit_m - EPS_M;
        let seen_before = pts[within(&pts, a, b)]
            .iter()
            .take_while(|p| p.along_m < cut_m)
            .map(|p| p.spacing_m)
            .reduce(f64::min);
        // One step apart, with the feasibility test's rounding allowance: an
        // autopilot's checks 50 ms apart at 10 m/s give 0.5 m + 3e-14.
        let class = if strictly_between(&pts, a, b) == 0 || feasible(d, step_limit_m) {
            s.unavoidable_violations += 1;
            ViolationClass::Unavoidable
        } else if seen_before.is_none_or(|m| feasible(d, m)) {
            s.first_sight_violations += 1;
            ViolationClass::FirstSight
        } else {
            s.avoidable_violations += 1;
            s.worst_avoidable_excess_ratio = max_opt(s.worst_avoidable_excess_ratio, ratio);
            ViolationClass::Avoidable
        };
        s.violation_list.push(Violation {
            from_seq: w[0].seq,
            to_seq: w[1].seq,
            from_along_m: a,
            to_along_m: b,
            truth_spacing_m: m,
            ratio,
            class,
        });
    }

    // The stretch flown with captures; the whole track without any.
    let stretch = match (caps.first(), caps.last()) {
        (Some(a), Some(b)) => Some((a.along_m, b.along_m)),
        _ => None,
    };
    let (lo, hi) = stretch.unwrap_or((f64::NEG_INFINITY, f64::INFINITY));
    let in_stretch: Vec<&TrackSample> = truth
        .iter()
        .filter(|t| t.along_m >= lo - EPS_M && t.along_m <= hi + EPS_M)
        .collect();
    s.fallback_samples = in_stretch
        .iter()
        .filter(|t| !matches!(t.spacing_m, Some(v) if v.is_finite() && v > 0.0))
        .count();
    s.spacing_m = median(
        in_stretch
            .iter()
            .map(|t| in_force(t.spacing_m, fallback_m))
            .collect(),
    );

    let Some((first, last)) = stretch else {
        return s;
    };
    s.stretch_m = last - first;
    if let (Some(i), Some(j)) = (nearest(&pts, first), nearest(&pts, last)) {
        let (n, forced) = ideal(&pts, i, j.max(i));
        s.ideal_captures = Some(n);
        s.ideal_unavoidable = forced;
        s.ratio_to_ideal = Some(s.captures as f64 / n as f64);
    }
    if let Some(spacing) = min_over(&pts, first, last) {
        let fixed = (s.stretch_m / spacing + 1e-9).floor() as usize + 1;
        s.fixed_spacing_m = Some(spacing);
        s.fixed_captures = Some(fixed);
        s.data_ratio = Some(s.captures as f64 / fixed as f64);
    }
    s
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "n/a".to_string(), |x| format!("{x:.digits$}"))
}

fn opt_n(v: Option<usize>) -> String {
    v.map_or_else(|| "n/a".to_string(), |x| x.to_string())
}

/// The bounds a quality target stands for, in `spacing.active_bound`.
const TARGET_BOUNDS: [(&str, &[&str]); 4] = [
    ("parallax", &["parallax", "closed_loop_parallax"]),
    ("forward_overlap", &["forward_overlap"]),
    (
        "unseen_fraction",
        &["unseen_fraction", "closed_loop_unseen_fraction"],
    ),
    ("views_per_point", &["views_per_point"]),
];

impl Summary {
    /// Counts which bound set each capture's spacing and which terms each
    /// capture's estimate used, from the manifest.
    pub fn with_records(mut self, records: &[CaptureRecord]) -> Summary {
        for r in records {
            *self
                .captures_by_bound
                .entry(r.spacing.active_bound.clone())
                .or_default() += 1;
            for t in &r.terms {
                *self.captures_by_term.entry(t.clone()).or_default() += 1;
            }
            if self.quality_targets.is_none() {
                self.quality_targets = r.quality.as_ref().map(|q| q.targets.clone());
            }
        }
        self
    }

    /// Sets what the truth judged the flight by ([`Summary::judged_by`]).
    pub fn judged_by(mut self, judged_by: Option<String>) -> Summary {
        self.judged_by = judged_by;
        self
    }

    /// The targets in force that set no capture's spacing, with why not in
    /// words an operator can act on.
    pub fn never_bound(&self) -> Vec<String> {
        let Some(t) = &self.quality_targets else {
            return Vec::new();
        };
        let in_force = [
            t.parallax_px.is_some(),
            t.forward_overlap.is_some(),
            true,
            true,
        ];
        TARGET_BOUNDS
            .iter()
            .zip(in_force)
            .filter(|((_, bounds), on)| {
                *on && bounds
                    .iter()
                    .all(|b| !self.captures_by_bound.contains_key(*b))
            })
            .map(|((name, _), _)| match *name {
                "unseen_fraction" => {
                    let n = self.captures_by_term.get("visibility").copied().unwrap_or(0);
                    format!(
                        "unseen_fraction (occluders on {n} of {} captures; a tighter target set every spacing)",
                        self.captures
                    )
                }
                other => other.to_string(),
            })
            .collect()
    }

    /// A few aligned lines for the terminal.
    pub fn render_text(&self) -> String {
        let worst = self
            .worst_excess_ratio
            .map_or(String::new(), |r| format!(", worst {r:.3}x the spacing"));
        let range = self.spacing_m.map_or_else(
            || "n/a".to_string(),
            |r| {
                format!(
                    "{:.2} / {:.2} / {:.2} m (min / median / max)",
                    r.min_m, r.median_m, r.max_m
                )
            },
        );
        [
            format!(
                "{:<16}{} over {:.1} m ({} truth samples over {:.1} m)",
                "captures", self.captures, self.stretch_m, self.truth_samples, self.track_length_m
            ),
            format!(
                "{:<16}{} ({} forced steps); captures/ideal {}",
                "ideal",
                opt_n(self.ideal_captures),
                self.ideal_unavoidable,
                opt(self.ratio_to_ideal, 3)
            ),
            format!(
                "{:<16}{} ({} unavoidable, {} at first sight, {} avoidable){worst}",
                "violations",
                self.violations,
                self.unavoidable_violations,
                self.first_sight_violations,
                self.avoidable_violations
            ),
            // Three flags of their own: "0 flagged (…, fallback 2)" read as two of none.
            format!(
                "{:<16}{} flagged; {} rate-limited, {} on the fallback spacing",
                "under-sampled", self.undersampled, self.rate_limited, self.fallback
            ),
            format!(
                "{:<16}{} captures at {} m; data ratio {}",
                "fixed baseline",
                opt_n(self.fixed_captures),
                opt(self.fixed_spacing_m, 3),
                opt(self.data_ratio, 3)
            ),
            format!("{:<16}{range}", "spacing"),
        ]
        .into_iter()
        .chain(
            self.judged_by
                .as_ref()
                .map(|j| format!("{:<16}{j}", "judged by")),
        )
        .chain(self.quality_targets.as_ref().map(|t| {
            let targets = crate::report::targets_text(
                t.parallax_px,
                t.forward_overlap,
                t.unseen_fraction_max,
                t.views_per_point_min,
            );
            format!("{:<16}{}: {targets}", "targets", t.profile)
        }))
        .chain((!self.captures_by_bound.is_empty()).then(|| {
            let mut v: Vec<(&String, &usize)> = self.captures_by_bound.iter().collect();
            v.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
            let parts: Vec<String> = v.iter().map(|(b, n)| format!("{b} {n}")).collect();
            format!("{:<16}{}", "bound by", parts.join(", "))
        }))
        .chain((!self.captures_by_term.is_empty()).then(|| {
            let parts: Vec<String> = self
                .captures_by_term
                .iter()
                .map(|(t, n)| format!("{t} {n}"))
                .collect();
            format!("{:<16}{}", "terms used", parts.join(", "))
        }))
        .chain({
            let never = self.never_bound();
            (!never.is_empty()).then(|| format!("{:<16}{}", "never bound", never.join("; ")))
        })
        .chain(self.avoidable_lines())
        .collect::<Vec<_>>()
        .join("\n")
    }

    /// Where the avoidable violations are (the first few; `summary.json` has them all).
    fn avoidable_lines(&self) -> Vec<String> {
        let avoidable: Vec<&Violation> = self
            .violation_list
            .iter()
            .filter(|v| v.class == ViolationClass::Avoidable)
            .collect();
        let mut out: Vec<String> = avoidable
            .iter()
            .take(LISTED)
            .map(|v| {
                format!(
                    "{:<16}captures {}-{} at {:.2}-{:.2} m: {:.3} m flown against {:.3} m ({:.3}x)",
                    "avoidable",
                    v.from_seq,
                    v.to_seq,
                    v.from_along_m,
                    v.to_along_m,
                    v.to_along_m - v.from_along_m,
                    v.truth_spacing_m,
                    v.ratio
                )
            })
            .collect();
        if avoidable.len() > LISTED {
            out.push(format!(
                "{:<16}and {} more (summary.json, violation_list)",
                "avoidable",
                avoidable.len() - LISTED
            ));
        }
        out
    }

    /// The targets: `(target, met, the figure)`.
    pub fn targets(&self) -> Vec<(String, bool, String)> {
        let ideal = match (self.ideal_captures, self.ratio_to_ideal) {
            (Some(n), Some(r)) => (
                r <= 1.08 + 1e-12,
                format!(
                    "{} captures against an ideal {n}: {r:.3}x (target <= 1.08)",
                    self.captures
                ),
            ),
            _ => (
                false,
                "no ideal count (no captures or no truth)".to_string(),
            ),
        };
        let data = match (self.fixed_captures, self.data_ratio) {
            (Some(n), Some(r)) => (
                r <= 0.6 + 1e-12,
                format!(
                    "{} captures against {n} at a fixed {} m: {r:.3} (target <= 0.6)",
                    self.captures,
                    opt(self.fixed_spacing_m, 3)
                ),
            ),
            _ => (
                false,
                "no fixed-distance baseline (no captures or no truth)".to_string(),
            ),
        };
        vec![
            (
                "0 avoidable violations".to_string(),
                self.avoidable_violations == 0,
                format!(
                    "{} avoidable spacing violations ({} unavoidable, {} at first sight){}",
                    self.avoidable_violations,
                    self.unavoidable_violations,
                    self.first_sight_violations,
                    self.worst_avoidable_excess_ratio
                        .map_or(String::new(), |r| format!(", worst {r:.3}x"))
                ),
            ),
            ("captures <= 1.08 x ideal".to_string(), ideal.0, ideal.1),
            ("data ratio <= 0.6".to_string(), data.0, data.1),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn captures_are_counted_per_bound_and_term_and_silent_targets_named() {
        use crate::capture::{QualityRecord, QualitySpacingM, QualityValues};
        let targets = QualityTargets {
            profile: "lightfield".into(),
            parallax_px: Some(2.0),
            forward_overlap: None,
            unseen_fraction_max: 0.002,
            views_per_point_min: 2,
        };
        let records: Vec<CaptureRecord> = (1..=5)
            .map(|k| {
                let mut r = crate::capture::record::tests::sample(k);
                r.spacing.active_bound = if k <= 3 {
                    "parallax"
                } else {
                    "views_per_point"
                }
                .into();
                r.terms = if k == 1 {
                    vec!["parallax".into(), "views".into()]
                } else {
                    vec!["parallax".into(), "views".into(), "visibility".into()]
                };
                r.quality = Some(QualityRecord {
                    targets: targets.clone(),
                    spacing_m: QualitySpacingM {
                        parallax: Some(1.0),
                        forward_overlap: None,
                        unseen_fraction: None,
                        views_per_point: Some(2.0),
                    },
                    predicted: QualityValues {
                        parallax_px: Some(2.0),
                        forward_overlap: None,
                        unseen_fraction: Some(0.0),
                        views_per_point: Some(4),
                    },
                });
                r
            })
            .collect();
        let s = summarize(&[], &[], 1.0, 0.0).with_records(&records);
        assert_eq!(s.captures_by_bound["parallax"], 3);
        assert_eq!(s.captures_by_bound["views_per_point"], 2);
        assert_eq!(s.captures_by_term["visibility"], 4);
        assert_eq!(s.quality_targets, Some(targets));
        // Forward overlap is not in force; the unseen fraction is and never bound.
        let never = s.never_bound();
        assert_eq!(never.len(), 1, "{never:?}");
        assert!(
            never[0].starts_with("unseen_fraction (occluders on 4 of"),
            "{never:?}"
        );
        let text = s.render_text();
        assert!(
            text.contains("bound by        parallax 3, views_per_point 2"),
            "{text}"
        );
        assert!(
            text.contains("targets         lightfield: parallax 2 px, forward overlap off"),
            "{text}"
        );
    }

    fn sample(along_m: f64, spacing_m: Option<f64>) -> TrackSample {
        TrackSample {
            mono_ns: (along_m * 1e8) as u64,
            along_m,
            north_m: along_m,
            east_m: 0.0,
            spacing_m,
            active_bound: None,
            occlusion_degree: None,
            mmds_m: None,
        }
    }

    fn capture(seq: u64, along_m: f64) -> CaptureAt {
        CaptureAt {
            seq,
            mono_ns: (along_m * 1e8) as u64,
            along_m,
            decided_along_m: along_m,
            north_m: along_m,
            east_m: 0.0,
            undersampled: false,
            rate_limited: false,
            fallback: false,
        }
    }

    /// Samples every 0.1 m over [0, 10] with `spacing(along)`.
    fn track(spacing: impl Fn(f64) -> Option<f64>) -> Vec<TrackSample> {
        (0..=100)
            .map(|k| {
                let x = k as f64 / 10.0;
                sample(x, spacing(x))
            })
            .collect()
    }

    /// Captures at `k·step` for every `k` with `k·step ≤ end`.
    fn every(step_dm: usize, end_dm: usize) -> Vec<CaptureAt> {
        (0..=end_dm)
            .step_by(step_dm)
            .enumerate()
            .map(|(i, k)| capture(i as u64 + 1, k as f64 / 10.0))
            .collect()
    }

    #[test]
    fn captures_exactly_at_a_constant_spacing_are_ideal() {
        let s = summarize(&track(|_| Some(1.0)), &every(10, 100), 1.0, 0.0);
        assert_eq!(s.captures, 11);
        assert_eq!(s.ideal_captures, Some(11));
        assert_eq!(s.ideal_unavoidable, 0);
        assert_eq!(s.ratio_to_ideal, Some(1.0));
        assert_eq!((s.violations, s.worst_excess_ratio), (0, None));
        assert_eq!(s.fixed_spacing_m, Some(1.0));
        assert_eq!(s.fixed_captures, Some(11));
        assert_eq!(s.data_ratio, Some(1.0));
        assert_eq!(s.stretch_m, 10.0);
        assert_eq!(s.track_length_m, 10.0);
        let r = s.spacing_m.unwrap();
        assert_eq!((r.min_m, r.median_m, r.max_m), (1.0, 1.0, 1.0));
        let t = s.targets();
        assert_eq!(t.len(), 3);
        assert!(t[0].1 && t[1].1, "{t:?}");
        // A fixed trigger at the same spacing takes as many: ratio 1 > 0.6.
        assert!(!t[2].1);
        assert!(t[2].2.contains("1.000"), "{}", t[2].2);
        let text = s.render_text();
        assert!(text.contains("captures        11"), "{text}");
        assert!(text.contains("ideal           11"), "{text}");
    }

    #[test]
    fn captures_every_1_2_m_violate_each_interval_by_1_2() {
        let s = summarize(&track(|_| Some(1.0)), &every(12, 100), 1.0, 0.0);
        // 0, 1.2, …, 9.6: eight intervals, each 1.2 m against 1 m.
        assert_eq!(s.captures, 9);
        assert_eq!(s.violations, 8);
        assert_eq!(s.avoidable_violations, 8);
        assert_eq!(s.unavoidable_violations, 0);
        assert!((s.worst_excess_ratio.unwrap() - 1.2).abs() < 1e-9);
        assert!((s.worst_avoidable_excess_ratio.unwrap() - 1.2).abs() < 1e-9);
        // Ideal over [0, 9.6]: 0, 1, …, 9, 9.6.
        assert_eq!(s.ideal_captures, Some(11));
        assert_eq!(s.fixed_captures, Some(10));
        assert!(!s.targets()[0].1);
        // Each listed where it is; the text names the first five and counts the rest.
        assert_eq!(s.violation_list.len(), 8);
        let v = s.violation_list[2];
        assert_eq!(
            (v.from_seq, v.to_seq, v.class),
            (3, 4, ViolationClass::Avoidable)
        );
        assert!((v.from_along_m - 2.4).abs() < 1e-9 && (v.to_along_m - 3.6).abs() < 1e-9);
        assert!((v.truth_spacing_m - 1.0).abs() < 1e-12 && (v.ratio - 1.2).abs() < 1e-9);
        let text = s.render_text();
        assert!(
            text.contains("avoidable       captures 3-4 at 2.40-3.60 m: 1.200 m flown against 1.000 m (1.200x)"),
            "{text}"
        );
        assert!(!text.contains("captures 6-7"), "{text}");
        assert!(text.contains("and 3 more"), "{text}");
        let json = serde_json::to_value(&s).unwrap();
        assert_eq!(json["violation_list"][0]["class"], "avoidable");
    }

    #[test]
    fn a_dip_in_the_spacing_costs_two_captures() {
        let t = track(|x| Some(if (4.0..=5.0).contains(&x) { 0.5 } else { 1.0 }));
        // By hand: 0, 1, 2, 3, 3.9 (4.0 would span the dip's 0.5 m at 1 m),
        // 4.4, 4.9, 5.4 (5.0 is in the dip), 6.4, 7.4, 8.4, 9.4, 10.
        let s = summarize(&t, &every(10, 100), 1.0, 0.0);
        assert_eq!(s.ideal_captures, Some(13));
        // Captures every metre cross the dip: [3,4], [4,5], [5,6] are too long.
        assert_eq!(s.violations, 3);
        let at: Vec<(u64, u64)> = s
            .violation_list
            .iter()
            .map(|v| (v.from_seq, v.to_seq))
            .collect();
        assert_eq!(at, [(4, 5), (5, 6), (6, 7)]);
        assert!((s.worst_excess_ratio.unwrap() - 2.0).abs() < 1e-9);
        assert_eq!(s.fixed_spacing_m, Some(0.5));
        assert_eq!(s.fixed_captures, Some(21));
        let r = s.spacing_m.unwrap();
        assert_eq!((r.min_m, r.median_m, r.max_m), (0.5, 1.0, 1.0));
    }

    #[test]
    fn a_drop_shown_first_by_the_closing_frame_is_at_first_sight_a_later_one_avoidable() {
        let t = track(|x| Some(if x < 5.0 - 1e-9 { 1.0 } else { 0.3 }));
        let at = |xs: &[f64]| -> Vec<CaptureAt> {
            xs.iter()
                .enumerate()
                .map(|(i, &x)| capture(i as u64 + 1, x))
                .collect()
        };
        // Captured at the frame that first shows 0.3 m: [4, 5] spans only it.
        let s = summarize(&t, &at(&[0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 5.3, 5.6]), 1.0, 0.0);
        assert_eq!(s.violations, 1);
        assert_eq!(s.first_sight_violations, 1);
        assert_eq!(s.avoidable_violations, 0);
        assert!(s.targets()[0].1);
        assert!(s.render_text().contains("1 at first sight, 0 avoidable"));
        // A frame late: 5.0 showed 0.3 m before the capture at 5.1 closed [4, 5.1].
        let s = summarize(&t, &at(&[0.0, 1.0, 2.0, 3.0, 4.0, 5.1, 5.4]), 1.0, 0.0);
        assert_eq!(s.violations, 1);
        assert_eq!(s.first_sight_violations, 0);
        assert_eq!(s.avoidable_violations, 1);
        // An external camera's pictures 1 m apart, the last at 5.1 past 5.0's 0.3 m: taken
        // where decided, avoidable (5.0 showed it before the capture at 5.1).
        let mut late = at(&[0.1, 1.1, 2.1, 3.1, 4.1, 5.1, 5.4]);
        let s = summarize(&t, &late, 1.0, 0.0);
        assert_eq!((s.violations, s.avoidable_violations), (1, 1));
        // Each commanded 0.15 m (at 10 m/s, 15 ms) before its picture: the one at 5.1 was
        // decided at 4.95, before 5.0 showed 0.3 m.
        for c in &mut late {
            c.decided_along_m = c.along_m - 0.15;
        }
        let s = summarize(&t, &late, 1.0, 0.0);
        assert_eq!(s.violations, 1);
        assert_eq!(s.first_sight_violations, 1);
        assert_eq!(s.avoidable_violations, 0);
        // Decided 0.05 m before (at 5.05): 5.0 had shown it.
        for c in &mut late {
            c.decided_along_m = c.along_m - 0.05;
        }
        let s = summarize(&t, &late, 1.0, 0.0);
        assert_eq!(s.avoidable_violations, 1);
        // Decided 1.2 m before: nothing of [4.1, 5.1] had been seen, at first sight.
        for c in &mut late {
            c.decided_along_m = c.along_m - 1.2;
        }
        let s = summarize(&t, &late, 1.0, 0.0);
        assert_eq!(s.first_sight_violations, 1);
        // The dip below: [3, 4] is at first sight, [4, 5] and [5, 6] are not.
        let dip = track(|x| Some(if (4.0..=5.0).contains(&x) { 0.5 } else { 1.0 }));
        let s = summarize(&dip, &every(10, 100), 1.0, 0.0);
        assert_eq!(
            (
                s.violations,
                s.first_sight_violations,
                s.avoidable_violations
            ),
            (3, 1, 2)
        );
    }

    #[test]
    fn no_estimate_means_the_fallback_spacing() {
        let t = track(|x| if x < 5.0 { Some(1.0) } else { None });
        // Fallback 0.5 beyond 5 m: every 0.5 m there is right, every 1 m is not.
        let s = summarize(&t, &every(5, 100), 0.5, 0.0);
        assert_eq!(s.violations, 0);
        assert_eq!(s.fallback_samples, 51);
        assert_eq!(s.fixed_spacing_m, Some(0.5));
        let s = summarize(&t, &every(10, 100), 0.5, 0.0);
        // [4, 5] includes 5.0 (no estimate) and [5,6] … [9,10]: six intervals.
        assert_eq!(s.violations, 6);
        // Ideal: 0 … 4, 4.9 (5.0 has no estimate: 0.5 m), 5.4 … 9.9 every
        // 0.5 m, 10.
        assert_eq!(s.ideal_captures, Some(5 + 1 + 10 + 1));
    }

    #[test]
    fn steps_longer_than_the_spacing_are_unavoidable() {
        let t: Vec<_> = (0..6).map(|k| sample(2.0 * k as f64, Some(1.0))).collect();
        let caps: Vec<_> = (0..6).map(|k| capture(k + 1, 2.0 * k as f64)).collect();
        let s = summarize(&t, &caps, 1.0, 0.0);
        assert_eq!(s.violations, 5);
        assert_eq!(s.unavoidable_violations, 5);
        assert_eq!(s.avoidable_violations, 0);
        assert_eq!(s.worst_avoidable_excess_ratio, None);
        assert_eq!(s.worst_excess_ratio, Some(2.0));
        assert_eq!(s.ideal_captures, Some(6));
        assert_eq!(s.ideal_unavoidable, 5);
        assert!(s.targets()[0].1);
    }

    #[test]
    fn the_step_limit_excuses_intervals_of_one_opportunity_step() {
        let t = track(|_| Some(0.25));
        let caps = vec![capture(1, 0.0), capture(2, 0.3), capture(3, 0.6)];
        let s = summarize(&t, &caps, 1.0, 0.0);
        assert_eq!((s.violations, s.avoidable_violations), (2, 2));
        let s = summarize(&t, &caps, 1.0, 0.3);
        assert_eq!((s.violations, s.unavoidable_violations), (2, 2));
        // One step but for the rounding of its ends (1.1 − 0.6 = 0.5 + 1e-16),
        // as PX4's 50 ms checks at 10 m/s give.
        let caps = vec![capture(1, 0.6), capture(2, 1.1)];
        assert!(
            std::hint::black_box(1.1) - 0.6 > 0.5,
            "the premise: rounded past 0.5"
        );
        let s = summarize(&t, &caps, 1.0, 0.5);
        assert_eq!((s.violations, s.unavoidable_violations), (1, 1));
    }

    #[test]
    fn daemon_flags_are_counted() {
        let mut caps = every(10, 100);
        caps[3].undersampled = true;
        caps[3].rate_limited = true;
        caps[5].fallback = true;
        let s = summarize(&track(|_| Some(1.0)), &caps, 1.0, 0.0);
        assert_eq!((s.undersampled, s.rate_limited, s.fallback), (1, 1, 1));
        // Three counts of their own, not the fallback's inside the flagged.
        caps[3].undersampled = false;
        let s = summarize(&track(|_| Some(1.0)), &caps, 1.0, 0.0);
        assert!(
            s.render_text()
                .contains("under-sampled   0 flagged; 1 rate-limited, 1 on the fallback spacing\n"),
            "{}",
            s.render_text()
        );
    }

    #[test]
    fn empty_and_degenerate_inputs_give_no_figures_and_no_panic() {
        let s = summarize(&[], &[], 1.0, 0.0);
        assert_eq!(s.ideal_captures, None);
        assert_eq!(s.data_ratio, None);
        assert!(s.targets().iter().skip(1).all(|t| !t.1));
        let text = s.render_text();
        assert!(text.starts_with("captures"), "{text}");
        assert!(!text.contains("NaN") && !text.contains("inf"), "{text}");
        // Captures without truth: intervals cannot be judged.
        let s = summarize(&[], &every(10, 30), 1.0, 0.0);
        assert_eq!((s.violations, s.unjudged_intervals), (0, 3));
        // Truth without captures: the spacing range of the whole track.
        let s = summarize(&track(|_| Some(2.0)), &[], f64::NAN, 0.0);
        assert_eq!(s.spacing_m.unwrap().median_m, 2.0);
        assert_eq!(s.ideal_captures, None);
        // One capture: the ideal is that capture.
        let s = summarize(&track(|_| Some(1.0)), &every(10, 0), 1.0, 0.0);
        assert_eq!((s.ideal_captures, s.fixed_captures), (Some(1), Some(1)));
        // NaN positions and spacings are skipped.
        let mut t = track(|_| Some(1.0));
        t[7].along_m = f64::NAN;
        t[8].spacing_m = Some(f64::NAN);
        let s = summarize(&t, &every(10, 100), 1.0, 0.0);
        assert_eq!((s.violations, s.ideal_captures), (0, Some(11)));
        serde_json::to_string(&s).unwrap();
    }

    /// The fewest allowed captures from sample `s` to `e` by dynamic programming.
    fn brute_force(t: &[(f64, f64)], s: usize, e: usize) -> usize {
        let mut best = vec![usize::MAX; t.len()];
        best[s] = 1;
        for j in s + 1..=e {
            for i in s..j {
                let m = t[i..=j].iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
                let allowed = j == i + 1 || t[j].0 - t[i].0 <= m * (1.0 + REL_TOL);
                if allowed && best[i] != usize::MAX {
                    best[j] = best[j].min(best[i] + 1);
                }
            }
        }
        best[e]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        #[test]
        fn greedy_ideal_is_the_minimum(
            steps in prop::collection::vec((0.05f64..2.0, prop::option::weighted(0.85, 0.1f64..3.0)), 1..14),
            ends in (0usize..14, 0usize..14),
            fallback in 0.1f64..3.0,
        ) {
            let mut x = 0.0;
            let mut t = vec![sample(0.0, Some(1.0))];
            for &(dx, sp) in &steps {
                x += dx;
                t.push(sample(x, sp));
            }
            let n = t.len();
            let (s, e) = (ends.0.min(n - 1), ends.1.min(n - 1));
            let (s, e) = (s.min(e), s.max(e));
            let caps = [capture(1, t[s].along_m), capture(2, t[e].along_m)];
            let got = summarize(&t, &caps, fallback, 0.0);
            let pts: Vec<(f64, f64)> =
                t.iter().map(|p| (p.along_m, in_force(p.spacing_m, fallback))).collect();
            prop_assert_eq!(got.ideal_captures, Some(brute_force(&pts, s, e)));
        }
    }
}
