//! Routes MuJoCo's messages to stderr instead of MuJoCo's default `./MUJOCO_LOG.TXT`.
//!
//! MuJoCo's default handler appends every warning to a log file in the current directory, which
//! litters whatever directory a user or test runs in. The handler here prints warnings and errors
//! to stderr, each distinct message once per process (cheetah.xml's deprecated `settotalmass`
//! warns on every load), and drops informational messages.

use std::collections::HashSet;
use std::sync::{Mutex, Once};

use mujoco_rs::prelude::{MjLogMessage, MjtLogLevel, set_log_handler};

static INSTALL: Once = Once::new();
/// The subjects already printed.
static SEEN: Mutex<Option<HashSet<String>>> = Mutex::new(None);

fn to_stderr(message: &MjLogMessage) {
    let level = match message.level() {
        MjtLogLevel::mjLOG_ERROR => "error",
        MjtLogLevel::mjLOG_WARNING => "warning",
        _ => return,
    };
    if level == "warning" {
        let mut seen = SEEN.lock().unwrap_or_else(|e| e.into_inner());
        if !seen
            .get_or_insert_with(HashSet::new)
            .insert(message.subject().to_string())
        {
            return;
        }
    }
    match message.body() {
        Some(body) if !body.is_empty() => {
            eprintln!("mujoco {level}: {}\n{body}", message.subject())
        }
        _ => eprintln!("mujoco {level}: {}", message.subject()),
    }
}

/// Installs the handler (once per process) before the first MuJoCo call of this crate.
pub fn install() {
    INSTALL.call_once(|| {
        // SAFETY: `Once` serialises the call; this runs before this crate's first MuJoCo call
        // (model loading). Another crate in the same process calling MuJoCo concurrently during
        // this first call is the only hazard, and the workspace has no such crate.
        unsafe { set_log_handler(to_stderr) };
    });
}
