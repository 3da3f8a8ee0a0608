//! The Pareto front of (seconds, SSIM): the settings no other setting beats on both.

use super::row::Row;

/// Sets `pareto` on every row from its (seconds, SSIM).
pub fn mark_front(rows: &mut [Row]) {
    let points: Vec<(f64, f64)> = rows.iter().map(|r| (r.seconds, r.ssim)).collect();
    for (r, on) in rows.iter_mut().zip(pareto_front(&points)) {
        r.pareto = on;
    }
}

/// Whether `a` dominates `b` in (seconds, SSIM): no slower, no worse, and strictly better in one.
/// False whenever a coordinate is NaN (every comparison with NaN is false).
pub fn dominates(a: (f64, f64), b: (f64, f64)) -> bool {
    a.0 <= b.0 && a.1 >= b.1 && (a.0 < b.0 || a.1 > b.1)
}

/// The Pareto front of `(seconds, ssim)` points: `true` for each point that no other point dominates
/// (fewer or equal seconds and higher or equal SSIM, strictly better in at least one).
///
/// Identical points do not dominate each other, so tied settings are on the front together. A point
/// with a NaN coordinate cannot be compared: it is never on the front and dominates nothing. Quadratic,
/// which is nothing next to one denoise per point.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    points
        .iter()
        .map(|&p| !(p.0.is_nan() || p.1.is_nan() || points.iter().any(|&q| dominates(q, p))))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_examples() {
        // (1, .8) and (2, .9) trade off; (3, .85) is beaten by (2, .9); (1, .7) by (1, .8).
        let pts = [(1.0, 0.8), (2.0, 0.9), (3.0, 0.85), (1.0, 0.7)];
        assert_eq!(pareto_front(&pts), [true, true, false, false]);
        // Identical points are both on the front.
        assert_eq!(
            pareto_front(&[(1.0, 0.9), (1.0, 0.9), (2.0, 0.9)]),
            [true, true, false]
        );
        // Same time, better SSIM wins; same SSIM, faster wins.
        assert_eq!(pareto_front(&[(1.0, 0.9), (1.0, 0.8)]), [true, false]);
        assert_eq!(pareto_front(&[(2.0, 0.9), (1.0, 0.9)]), [false, true]);
        assert_eq!(pareto_front(&[(f64::NAN, 0.9), (1.0, 0.5)]), [false, true]);
        assert!(pareto_front(&[]).is_empty());
        assert_eq!(pareto_front(&[(0.5, 0.1)]), [true]);
        // Property tests of the front are in tests/it/sweep.rs.
    }
}
