//! dm_control's `rewards.tolerance` with all of its sigmoids (`dm_control/utils/rewards.py`).
//!
//! The Control Suite builds every reward from this soft indicator. It is reproduced operation for
//! operation (same scale computations, same branch conditions) so rewards agree with dm_control to
//! the last few ulps; transcendental functions are the platform's (glibc), like numpy's.

/// The shape of the fall-off outside the bounds (`sigmoid=` in dm_control).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sigmoid {
    Gaussian,
    Hyperbolic,
    LongTail,
    Reciprocal,
    Cosine,
    Linear,
    Quadratic,
    TanhSquared,
}

/// dm_control's default `value_at_margin`.
pub const DEFAULT_VALUE_AT_MARGIN: f64 = 0.1;

/// `_sigmoids(x, value_at_1, sigmoid)`: 1 at `x == 0`, `value_at_1` at `|x| == 1`.
///
/// # Panics
/// If `value_at_1` is outside the range dm_control accepts for the sigmoid (a programming error:
/// every call site passes a constant).
pub fn sigmoid(x: f64, value_at_1: f64, kind: Sigmoid) -> f64 {
    use core::f64::consts::PI;
    match kind {
        Sigmoid::Cosine | Sigmoid::Linear | Sigmoid::Quadratic => {
            assert!(
                (0.0..1.0).contains(&value_at_1),
                "value_at_1 must be in [0, 1)"
            )
        }
        _ => assert!(
            value_at_1 > 0.0 && value_at_1 < 1.0,
            "value_at_1 must be in (0, 1)"
        ),
    }
    match kind {
        Sigmoid::Gaussian => {
            let scale = (-2.0 * value_at_1.ln()).sqrt();
            let xs = x * scale;
            (-0.5 * (xs * xs)).exp()
        }
        Sigmoid::Hyperbolic => {
            let scale = (1.0 / value_at_1).acosh();
            1.0 / (x * scale).cosh()
        }
        Sigmoid::LongTail => {
            let scale = (1.0 / value_at_1 - 1.0).sqrt();
            let xs = x * scale;
            1.0 / (xs * xs + 1.0)
        }
        Sigmoid::Reciprocal => {
            let scale = 1.0 / value_at_1 - 1.0;
            1.0 / (x.abs() * scale + 1.0)
        }
        Sigmoid::Cosine => {
            let scale = (2.0 * value_at_1 - 1.0).acos() / PI;
            let scaled_x = x * scale;
            if scaled_x.abs() < 1.0 {
                (1.0 + (PI * scaled_x).cos()) / 2.0
            } else {
                0.0
            }
        }
        Sigmoid::Linear => {
            let scale = 1.0 - value_at_1;
            let scaled_x = x * scale;
            if scaled_x.abs() < 1.0 {
                1.0 - scaled_x
            } else {
                0.0
            }
        }
        Sigmoid::Quadratic => {
            let scale = (1.0 - value_at_1).sqrt();
            let scaled_x = x * scale;
            if scaled_x.abs() < 1.0 {
                1.0 - scaled_x * scaled_x
            } else {
                0.0
            }
        }
        Sigmoid::TanhSquared => {
            let scale = (1.0 - value_at_1).sqrt().atanh();
            let t = (x * scale).tanh();
            1.0 - t * t
        }
    }
}

/// Arguments of `tolerance` other than `x`, with dm_control's defaults.
#[derive(Clone, Copy, Debug)]
pub struct Tolerance {
    pub bounds: (f64, f64),
    pub margin: f64,
    pub sigmoid: Sigmoid,
    pub value_at_margin: f64,
}

impl Default for Tolerance {
    fn default() -> Self {
        Self {
            bounds: (0.0, 0.0),
            margin: 0.0,
            sigmoid: Sigmoid::Gaussian,
            value_at_margin: DEFAULT_VALUE_AT_MARGIN,
        }
    }
}

impl Tolerance {
    /// `tolerance(x, bounds, margin, sigmoid, value_at_margin)`: 1 inside `bounds`, falling off
    /// outside over a distance `margin` (a hard 0 when `margin == 0`).
    pub fn eval(&self, x: f64) -> f64 {
        let (lower, upper) = self.bounds;
        assert!(lower <= upper, "lower bound must be <= upper bound");
        assert!(self.margin >= 0.0, "margin must be non-negative");
        let in_bounds = lower <= x && x <= upper;
        if self.margin == 0.0 {
            if in_bounds { 1.0 } else { 0.0 }
        } else if in_bounds {
            1.0
        } else {
            let d = if x < lower { lower - x } else { x - upper } / self.margin;
            sigmoid(d, self.value_at_margin, self.sigmoid)
        }
    }
}

/// `tolerance(x, bounds, margin, ...)` with the Gaussian sigmoid and default value at the margin.
pub fn tolerance(x: f64, bounds: (f64, f64), margin: f64) -> f64 {
    Tolerance {
        bounds,
        margin,
        ..Tolerance::default()
    }
    .eval(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [Sigmoid; 8] = [
        Sigmoid::Gaussian,
        Sigmoid::Hyperbolic,
        Sigmoid::LongTail,
        Sigmoid::Reciprocal,
        Sigmoid::Cosine,
        Sigmoid::Linear,
        Sigmoid::Quadratic,
        Sigmoid::TanhSquared,
    ];

    #[test]
    fn every_sigmoid_is_one_at_zero_and_value_at_one() {
        for kind in ALL {
            assert!(
                (sigmoid(0.0, 0.3, kind) - 1.0).abs() < 1e-15,
                "{kind:?} at 0"
            );
            assert!(
                (sigmoid(1.0, 0.3, kind) - 0.3).abs() < 1e-12,
                "{kind:?} at 1"
            );
            assert!((sigmoid(-1.0, 0.3, kind) - 0.3).abs() < 1e-12 || kind == Sigmoid::Linear);
        }
    }

    #[test]
    fn tolerance_is_one_inside_and_falls_off_outside() {
        let t = Tolerance {
            bounds: (1.0, 2.0),
            margin: 0.5,
            ..Tolerance::default()
        };
        assert_eq!(t.eval(1.5), 1.0);
        assert_eq!(t.eval(1.0), 1.0);
        assert!((t.eval(2.5) - 0.1).abs() < 1e-12);
        assert!((t.eval(0.5) - 0.1).abs() < 1e-12);
        assert_eq!(tolerance(3.0, (1.0, 2.0), 0.0), 0.0);
        assert_eq!(tolerance(f64::INFINITY, (0.0, f64::INFINITY), 0.0), 1.0);
    }

    #[test]
    fn linear_and_quadratic_reach_zero_at_the_margin() {
        // value_at_margin = 0 is legal for these two and gives a hard zero beyond the margin.
        let t = Tolerance {
            margin: 1.0,
            sigmoid: Sigmoid::Quadratic,
            value_at_margin: 0.0,
            ..Default::default()
        };
        assert_eq!(t.eval(1.0), 0.0);
        assert_eq!(t.eval(-1.5), 0.0);
        assert!((t.eval(0.5) - 0.75).abs() < 1e-15);
    }
}
