//! `Generator` against numbers printed by numpy's `Generator(PCG64(SeedSequence(seed)))` (the
//! fixture is written by `scripts/numpy_generator_fixture.py`): seeding, raw outputs and every
//! draw must match bit for bit, and 10^6 standard normals per seed must hash the same.

use serde_json::Value;
use sha2::{Digest, Sha256};
use sim_bridge::numpy_generator::{Generator, Pcg64, seed_sequence_state};

fn words(v: &Value) -> Vec<u64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_str().unwrap().parse().unwrap())
        .collect()
}

fn fixture() -> Value {
    serde_json::from_str(include_str!("fixtures/numpy_generator.json")).unwrap()
}

#[test]
fn seeding_and_raw_outputs_match_numpy() {
    let f = fixture();
    for case in f["cases"].as_array().unwrap() {
        let seed = case["seed"].as_u64().unwrap();
        assert_eq!(
            seed_sequence_state(seed).to_vec(),
            words(&case["seed_sequence_state"]),
            "seed {seed}: SeedSequence.generate_state(4, uint64)"
        );
        let mut bits = Pcg64::new(seed);
        let raw: Vec<u64> = (0..5).map(|_| bits.next_u64()).collect();
        assert_eq!(raw, words(&case["raw"]), "seed {seed}: PCG64.random_raw");
    }
}

#[test]
fn draws_match_numpy_bit_for_bit() {
    let f = fixture();
    let program = f["program"].as_array().unwrap();
    for case in f["cases"].as_array().unwrap() {
        let seed = case["seed"].as_u64().unwrap();
        let mut g = Generator::new(seed);
        let want = case["values"].as_array().unwrap();
        assert_eq!(want.len(), program.len());
        for (i, (op, want)) in program.iter().zip(want).enumerate() {
            let op = op.as_array().unwrap();
            let got = match op[0].as_str().unwrap() {
                "random" => g.random(),
                "standard_normal" => g.standard_normal(),
                "uniform" => g.uniform(op[1].as_f64().unwrap(), op[2].as_f64().unwrap()),
                other => panic!("unknown draw {other}"),
            };
            let want = want.as_f64().unwrap();
            assert_eq!(
                got.to_bits(),
                want.to_bits(),
                "seed {seed}, draw {i} ({op:?}): {got:e} != numpy's {want:e}"
            );
        }
    }
}

#[test]
fn a_million_standard_normals_hash_as_numpys() {
    let f = fixture();
    let n = usize::try_from(f["long_normals"].as_u64().unwrap()).unwrap();
    for case in f["cases"].as_array().unwrap() {
        let seed = case["seed"].as_u64().unwrap();
        let mut g = Generator::new(seed);
        let mut h = Sha256::new();
        for _ in 0..n {
            h.update(g.standard_normal().to_le_bytes());
        }
        let got: String = h.finalize().iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(
            got,
            case["normals_sha256"].as_str().unwrap(),
            "seed {seed}: sha256 of {n} standard normals"
        );
    }
}
