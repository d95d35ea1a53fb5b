//! `RandomState` against numbers printed by numpy's legacy `RandomState` (the fixture is written
//! by `scripts/numpy_rng_fixture.py`): every value must match bit for bit.

use serde_json::Value;
use sim_bridge::numpy_rng::RandomState;

#[test]
fn reproduces_numpy_legacy_random_state() {
    let text = include_str!("fixtures/numpy_random_state.json");
    let fixture: Value = serde_json::from_str(text).unwrap();
    let program = fixture["program"].as_array().unwrap();
    let cases = fixture["cases"].as_array().unwrap();
    assert!(!cases.is_empty());
    for case in cases {
        let seed = case["seed"].as_u64().unwrap();
        let mut rng = RandomState::new(u32::try_from(seed).unwrap());
        let expected = case["values"].as_array().unwrap();
        assert_eq!(expected.len(), program.len());
        for (i, (op, want)) in program.iter().zip(expected).enumerate() {
            let op = op.as_array().unwrap();
            let got = match op[0].as_str().unwrap() {
                "random_sample" => rng.random_sample(),
                "standard_normal" => rng.standard_normal(),
                "uniform" => rng.uniform(op[1].as_f64().unwrap(), op[2].as_f64().unwrap()),
                other => panic!("unknown draw {other}"),
            };
            let want = want.as_f64().unwrap();
            assert_eq!(
                got.to_bits(),
                want.to_bits(),
                "seed {seed}, draw {i} ({op:?}): {got} != {want}"
            );
        }
    }
}
