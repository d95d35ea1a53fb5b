//! `rewards::Tolerance` against dm_control's `rewards.tolerance` for every sigmoid, in and out of
//! bounds, with infinite bounds, `value_at_margin = 0` and `margin = 0` (fixture written by
//! `scripts/tolerance_fixture.py` from dm_control 1.0.50 itself).

use serde_json::Value;
use sim_bridge::rewards::{Sigmoid, Tolerance};

fn sigmoid(name: &str) -> Sigmoid {
    match name {
        "gaussian" => Sigmoid::Gaussian,
        "hyperbolic" => Sigmoid::Hyperbolic,
        "long_tail" => Sigmoid::LongTail,
        "reciprocal" => Sigmoid::Reciprocal,
        "cosine" => Sigmoid::Cosine,
        "linear" => Sigmoid::Linear,
        "quadratic" => Sigmoid::Quadratic,
        "tanh_squared" => Sigmoid::TanhSquared,
        other => panic!("unknown sigmoid {other}"),
    }
}

#[test]
fn matches_dm_control_tolerance_for_every_sigmoid() {
    let fixture: Value = serde_json::from_str(include_str!("fixtures/tolerance.json")).unwrap();
    let rows = fixture["rows"].as_array().unwrap();
    let mut seen = std::collections::HashSet::new();
    for row in rows {
        let name = row["sigmoid"].as_str().unwrap();
        seen.insert(name);
        let t = Tolerance {
            bounds: (
                row["lower"].as_str().unwrap().parse().unwrap(),
                row["upper"].as_str().unwrap().parse().unwrap(),
            ),
            margin: row["margin"].as_f64().unwrap(),
            sigmoid: sigmoid(name),
            value_at_margin: row["value_at_margin"].as_f64().unwrap(),
        };
        let x = row["x"].as_f64().unwrap();
        let want = row["value"].as_f64().unwrap();
        let got = t.eval(x);
        assert!(
            (got - want).abs() <= 1e-14,
            "{name} {t:?} at {x}: {got:e}, dm_control {want:e}"
        );
    }
    assert_eq!(seen.len(), 8, "every sigmoid covered");
}
