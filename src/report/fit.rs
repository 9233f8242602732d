//! Observed orders of convergence and work-precision interpolation: plain functions over
//! (Δt, error) and (wall time, error) points, used by the accuracy report and testable on
//! synthetic ladders.
//!
//! # How the asymptotic part of a ladder is chosen
//!
//! [`fit_order`] fits log e = p log Δt + c by least squares on a window of consecutive ladder
//! points, chosen in three steps:
//!
//! 1. Points with a non-finite or non-positive error (failed runs) are dropped.
//! 2. **Round-off floor.** Starting from the smallest Δt, a point is dropped while its error
//!    falls by less than Δt^[`FLOOR_SLOPE`] against the next larger Δt (local slope below
//!    0.25): such a point measures the `f32` round-off of the particle state (or the reference
//!    run's own error), not the time discretisation.
//! 3. **Asymptotic window.** Among the runs of consecutive remaining points, the window is
//!    the longest one whose local slopes all lie within [`WINDOW_TOLERANCE`] (relative) of the
//!    window's own least-squares slope; among equally long ones, the one whose local slopes
//!    agree best, then the one at smaller Δt. Points left out at the large-Δt end are
//!    pre-asymptotic; points left out at the small-Δt end are contaminated by round-off or
//!    by the reference run's own error.
//!
//! The fitted slope over the window is the observed order; the window (number of points and
//! Δt range) is reported with it.
use std::cmp::Ordering;

/// Local slopes below this count as the round-off floor (step 2 of the module docs).
pub const FLOOR_SLOPE: f64 = 0.25;

/// Largest relative deviation |s − p|/|p| of a local slope s from the window slope p for the
/// pair to join the asymptotic window (step 3 of the module docs).
pub const WINDOW_TOLERANCE: f64 = 0.15;

/// One run of a Δt ladder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LadderPoint {
    /// Step size Δt \[s\].
    pub dt: f64,
    /// Error of the run (any norm; positive).
    pub error: f64,
}

/// The observed order of a ladder and the window it was fitted on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrderFit {
    /// Least-squares slope of log(error) against log(Δt) over the window.
    pub order: f64,
    /// Points in the window (≥ 2).
    pub points: usize,
    /// Smallest Δt of the window \[s\].
    pub dt_min: f64,
    /// Largest Δt of the window \[s\].
    pub dt_max: f64,
    /// Points left out at the small-Δt end (round-off floor, or outside the window).
    pub floor_points: usize,
    /// Points left out at the large-Δt end (pre-asymptotic).
    pub coarse_points: usize,
}

/// Least-squares slope and intercept of y against x; `None` for fewer than two distinct x.
pub fn least_squares(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    let n = points.len() as f64;
    if points.len() < 2 {
        return None;
    }
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if sxx <= 0.0 || !sxx.is_finite() {
        return None;
    }
    let slope = sxy / sxx;
    Some((slope, my - slope * mx))
}

fn local_slope(a: &LadderPoint, b: &LadderPoint) -> f64 {
    (b.error.ln() - a.error.ln()) / (b.dt.ln() - a.dt.ln())
}

fn window_slope(points: &[LadderPoint]) -> Option<f64> {
    let logs: Vec<(f64, f64)> = points.iter().map(|p| (p.dt.ln(), p.error.ln())).collect();
    least_squares(&logs).map(|(s, _)| s)
}

/// The observed order of a Δt ladder, fitted on its asymptotic part (module docs); `None`
/// if fewer than two usable points remain.
pub fn fit_order(points: &[LadderPoint]) -> Option<OrderFit> {
    let mut pts: Vec<LadderPoint> = points
        .iter()
        .copied()
        .filter(|p| p.dt > 0.0 && p.dt.is_finite() && p.error > 0.0 && p.error.is_finite())
        .collect();
    pts.sort_by(|a, b| a.dt.partial_cmp(&b.dt).unwrap_or(Ordering::Equal));
    pts.dedup_by(|a, b| a.dt == b.dt);
    let usable = pts.len();
    // Step 2: round-off floor at the small-Δt end.
    let mut first = 0;
    while usable - first >= 2 && local_slope(&pts[first], &pts[first + 1]) < FLOOR_SLOPE {
        first += 1;
    }
    if usable - first < 2 {
        return None;
    }
    // Step 3: the longest consistent window; ties: best agreement, then smaller Δt.
    let mut best: Option<(usize, f64, usize, usize)> = None; // (len, deviation, i, j)
    for i in first..usable - 1 {
        for j in i + 1..usable {
            let w = &pts[i..=j];
            let Some(p) = window_slope(w) else {
                continue;
            };
            let dev = w
                .windows(2)
                .map(|a| (local_slope(&a[0], &a[1]) - p).abs() / p.abs().max(1e-12))
                .fold(0.0, f64::max);
            if dev > WINDOW_TOLERANCE {
                continue;
            }
            let len = w.len();
            let better = match best {
                None => true,
                Some((bl, bd, _, _)) => len > bl || (len == bl && dev < bd - 1e-12),
            };
            if better {
                best = Some((len, dev, i, j));
            }
        }
    }
    let (_, _, i, j) = best?;
    let window = &pts[i..=j];
    Some(OrderFit {
        order: window_slope(window)?,
        points: window.len(),
        dt_min: window[0].dt,
        dt_max: window[window.len() - 1].dt,
        floor_points: i,
        coarse_points: usable - 1 - j,
    })
}

/// The wall time at which a method reaches `level`, from its runs `(wall_seconds, error)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reach {
    /// Interpolated linearly in log(wall) against log(error) between the two runs whose
    /// errors bracket `level` \[s\].
    Interpolated(f64),
    /// Even the cheapest run is more accurate than `level`: reached in at most this time \[s\].
    AtMost(f64),
    /// No run is as accurate as `level`.
    NotReached,
}

impl Reach {
    /// The time, if reached (the bound for [`Reach::AtMost`]).
    pub fn seconds(&self) -> Option<f64> {
        match *self {
            Reach::Interpolated(s) | Reach::AtMost(s) => Some(s),
            Reach::NotReached => None,
        }
    }
}

/// When a method reaches error `level` in work-precision terms. `runs` are its ladder runs as
/// `(wall_seconds, error)`, in any order; they are walked from the cheapest to the most
/// expensive and the first pair that brackets `level` is interpolated (log-log).
pub fn time_to_reach(runs: &[(f64, f64)], level: f64) -> Reach {
    let mut pts: Vec<(f64, f64)> = runs
        .iter()
        .copied()
        .filter(|(w, e)| *w > 0.0 && w.is_finite() && *e > 0.0 && e.is_finite())
        .collect();
    pts.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap_or(Ordering::Equal));
    let Some(&(w0, e0)) = pts.first() else {
        return Reach::NotReached;
    };
    if e0 <= level {
        return Reach::AtMost(w0);
    }
    for w in pts.windows(2) {
        let ((wa, ea), (wb, eb)) = (w[0], w[1]);
        if ea > level && eb <= level {
            let f = (level.ln() - ea.ln()) / (eb.ln() - ea.ln());
            return Reach::Interpolated((wa.ln() + f * (wb.ln() - wa.ln())).exp());
        }
    }
    Reach::NotReached
}

/// Up to `n` error levels for a work-precision comparison: geometrically spaced inside the
/// range every method covers (from the largest of the smallest errors to the smallest of the
/// largest errors), rounded to one significant digit; inside the union of the ranges if the
/// methods do not overlap. `ranges` holds each method's (smallest, largest) error.
pub fn error_levels(ranges: &[(f64, f64)], n: usize) -> Vec<f64> {
    let ranges: Vec<(f64, f64)> = ranges
        .iter()
        .copied()
        .filter(|(a, b)| *a > 0.0 && a.is_finite() && b.is_finite() && b >= a)
        .collect();
    if ranges.is_empty() || n == 0 {
        return Vec::new();
    }
    let lo_common = ranges.iter().map(|r| r.0).fold(0.0, f64::max);
    let hi_common = ranges.iter().map(|r| r.1).fold(f64::INFINITY, f64::min);
    let (lo, hi) = if lo_common < hi_common {
        (lo_common, hi_common)
    } else {
        (
            ranges.iter().map(|r| r.0).fold(f64::INFINITY, f64::min),
            ranges.iter().map(|r| r.1).fold(0.0, f64::max),
        )
    };
    let mut out: Vec<f64> = (1..=n)
        .map(|k| {
            let f = k as f64 / (n + 1) as f64;
            round_1sig((hi.ln() + f * (lo.ln() - hi.ln())).exp())
        })
        .collect();
    out.dedup();
    out
}

/// `v` rounded to one significant digit (3.4e-5 → 3e-5).
pub fn round_1sig(v: f64) -> f64 {
    if v <= 0.0 || !v.is_finite() {
        return v;
    }
    let e = v.log10().floor();
    let m = (v / 10f64.powf(e)).round();
    // Build from the decimal string so that 3e-5 prints as "3e-5", not 2.9999999999999997e-5.
    format!("{m}e{e}").parse().unwrap_or(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slope_of_a_line() {
        let (s, c) = least_squares(&[(0.0, 1.0), (1.0, 3.0), (2.0, 5.0)]).unwrap();
        assert!((s - 2.0).abs() < 1e-12 && (c - 1.0).abs() < 1e-12);
        assert!(least_squares(&[(1.0, 1.0)]).is_none());
    }

    #[test]
    fn reach_interpolates_in_log_log() {
        // error = 1/wall²: level 1e-2 is reached at wall 10.
        let runs = [(1.0, 1.0), (4.0, 1.0 / 16.0), (16.0, 1.0 / 256.0)];
        match time_to_reach(&runs, 1e-2) {
            Reach::Interpolated(w) => assert!((w - 10.0).abs() < 1e-9, "{w}"),
            r => panic!("{r:?}"),
        }
        assert_eq!(time_to_reach(&runs, 2.0), Reach::AtMost(1.0));
        assert_eq!(time_to_reach(&runs, 1e-3), Reach::NotReached);
    }

    #[test]
    fn levels_inside_common_range() {
        let l = error_levels(&[(1e-6, 1e-2), (1e-5, 1e-1)], 3);
        assert_eq!(l.len(), 3);
        assert!(l.iter().all(|v| (1e-5..=1e-2).contains(v)), "{l:?}");
        assert_eq!(round_1sig(3.4e-5), 3e-5);
    }
}
