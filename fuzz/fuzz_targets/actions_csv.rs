//! `sim-bridge replay`'s action file (cli::parse_actions, what read_actions does after reading
//! the file): every accepted row has the task's width of finite numbers, at most an episode of
//! rows; every error names the file; accepted values written back with Rust's shortest
//! round-trip formatting parse to the same bits.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use sim_bridge::cli::parse_actions;

const ROWS: usize = 1000;

fuzz_target!(|data: &[u8]| {
    let Some((&w, rest)) = data.split_first() else {
        return;
    };
    let width = 1 + w as usize % 6;
    // read_to_string rejects anything else.
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    let path = Path::new("fuzz.csv");
    match parse_actions(text, path, width, ROWS) {
        Ok(rows) => {
            assert!(rows.len() <= ROWS);
            for r in &rows {
                assert_eq!(r.len(), width);
                assert!(r.iter().all(|x| x.is_finite()));
            }
            let csv: String = rows
                .iter()
                .map(|r| {
                    let cols: Vec<String> = r.iter().map(|x| format!("{x}")).collect();
                    cols.join(",") + "\n"
                })
                .collect();
            let again = parse_actions(&csv, path, width, ROWS).expect("written rows parse");
            let bits = |rows: &[Vec<f64>]| -> Vec<u64> {
                rows.iter().flatten().map(|x| x.to_bits()).collect()
            };
            assert_eq!(bits(&rows), bits(&again));
        }
        Err(e) => assert!(
            e.0.starts_with("fuzz.csv"),
            "error without the file: {}",
            e.0
        ),
    }
});
