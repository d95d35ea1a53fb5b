//! Progress on long work: a bar on a terminal, plain lines on stderr otherwise. Messages
//! printed through it never tear the bar.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A progress bar (hidden when not wanted or when stderr is not a terminal) and the log
/// lines printed above it.
pub struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// A bar of `len` units drawn with the indicatif `template` when `show`, else hidden.
    pub fn new(show: bool, len: u64, template: &str) -> Self {
        let bar = if show {
            ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr())
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template(template)
                .expect("a valid template")
                .progress_chars("=> "),
        );
        Self { bar }
    }

    /// Prints a line on stderr above the bar.
    pub fn log(&self, msg: &str) {
        if self.bar.is_hidden() {
            eprintln!("{msg}");
        } else {
            self.bar.println(msg);
        }
    }

    /// True when nothing is drawn (the message need not be formatted).
    pub fn is_hidden(&self) -> bool {
        self.bar.is_hidden()
    }

    /// Moves the bar.
    pub fn set_position(&self, pos: u64) {
        self.bar.set_position(pos);
    }

    /// The text after the bar.
    pub fn set_message(&self, msg: String) {
        self.bar.set_message(msg);
    }

    /// Removes the bar (the work is done).
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }

    /// Leaves the bar where it is (the work failed).
    pub fn abandon(&self) {
        self.bar.abandon();
    }
}
