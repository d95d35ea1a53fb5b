//! `mpo tasks`: the built-in tasks' rows, and those of task files.

use std::path::PathBuf;

use sim_bridge::TaskDef;

use crate::rows::{self, Row};
use crate::settings::PolicyEvaluation;

/// `mpo tasks`: one line per row of every built-in task, then of each task file given (with
/// whether this build has a learner of the row's sizes).
pub fn tasks_listing(files: &[PathBuf]) -> String {
    let mut s = format!(
        "{:<28} {:>4} {:>3}  {:<10} {:>11} {:>20} {:>4} {:>3} {:>3}  {:<12} {:>5} {:>9}\n",
        "task",
        "obs",
        "act",
        "net",
        "actor",
        "critic",
        "B",
        "M",
        "N",
        "evaluation",
        "noise",
        "steps"
    );
    for &name in sim_bridge::TASKS {
        match rows::builtin(name) {
            Ok(t) => push_task(&mut s, &t, false),
            Err(e) => s.push_str(&format!("{name:<28} (cannot load: {e})\n")),
        }
    }
    for f in files {
        match TaskDef::from_file(f) {
            Ok(t) => push_task(&mut s, &t, true),
            // The error names the file.
            Err(e) => s.push_str(&format!("{e}\n")),
        }
    }
    s.push_str(
        "\nactor, critic: an MLP's two widths (A-B), or a residual network of width W, inner \
         width F and D blocks ([W,F]xD); K bins: a categorical critic over K atoms.\n\
         A row's whole configuration: mpo train --task T [--net N] --print-config \
         (a task file: --task-file F)\n",
    );
    s
}

fn push_task(s: &mut String, task: &TaskDef, check_build: bool) {
    let (name, spec) = (task.name(), task.spec());
    let (obs, act) = (spec.obs_dim, spec.act_dim);
    let rows = match rows::rows_of(task) {
        Ok(r) => r,
        Err(e) => {
            s.push_str(&format!("{name:<28} {obs:>4} {act:>3}  {e}\n"));
            return;
        }
    };
    if rows.is_empty() {
        s.push_str(&format!(
            "{name:<28} {obs:>4} {act:>3}  (no row: not trainable)\n"
        ));
    }
    for r in rows {
        s.push_str(&format!("{name:<28} {obs:>4} {act:>3}  {}", describe(&r)));
        if check_build && crate::registry::find(&r.sizes).is_err() {
            s.push_str("  (not in this build: `./mpo train` adds it)");
        }
        s.push('\n');
    }
}

fn describe(r: &Row) -> String {
    let z = &r.sizes;
    let eval = match r.mpo.policy_evaluation {
        PolicyEvaluation::Td => "td".to_string(),
        PolicyEvaluation::NStep => format!("{}-step", r.mpo.n_step),
        PolicyEvaluation::Retrace => format!("retrace {}", r.mpo.n_step),
    };
    let noise = match r.schedule.noise_pink {
        true => "pink".to_string(),
        false => r.schedule.noise_corr.to_string(),
    };
    // An MLP's two widths `A-B`; a residual network's width, inner width and blocks `[W,F]xD`
    // (as `spec!` writes them); a categorical critic's atoms after it.
    let net = |w: [usize; 2], blocks: usize| match blocks {
        0 => format!("{}-{}", w[0], w[1]),
        d => format!("[{},{}]x{d}", w[0], w[1]),
    };
    let critic = match z.bins {
        1 => net(z.critic, z.critic_blocks),
        k => format!("{} {k} bins", net(z.critic, z.critic_blocks)),
    };
    format!(
        "{:<10} {:>11} {:>20} {:>4} {:>3} {:>3}  {eval:<12} {noise:>5} {:>9}",
        r.net,
        net(z.actor, z.actor_blocks),
        critic,
        z.batch,
        z.m,
        z.n,
        r.steps
    )
}
