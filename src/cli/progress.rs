//! The terminal's rendering of the library's progress and messages
//! ([`nvtmm::observe`]): a progress bar per task on stderr, messages as
//! lines on stderr (printed above a bar that is showing).

use indicatif::{ProgressBar, ProgressStyle};
use nvtmm::observe::{Event, Observe, Observer};
use std::sync::{Arc, Mutex};

/// The observer `nvtmm` passes to the library: silent with `--quiet`.
pub fn terminal(quiet: bool) -> Observe {
    if quiet {
        Observe::none()
    } else {
        Observe::new(Arc::new(Terminal::default()))
    }
}

#[derive(Default)]
struct Terminal {
    bar: Mutex<Option<(String, ProgressBar)>>,
}

/// The bar of one task: length and template.
fn bar_for(task: &str, total: f64) -> ProgressBar {
    // "run" reports seconds: tenths make a smooth bar with the elapsed time.
    let (len, template) = match task {
        "run" => ((total * 10.0) as u64, "{bar:40} {elapsed}/{duration} {msg}"),
        "simulate" => (total as u64, "{bar:40} {pos}/{len} steps  t={msg}  eta {eta}"),
        _ => (total as u64, "{bar:40} {pos}/{len} {msg}"),
    };
    let b = ProgressBar::new(len);
    b.set_style(ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()));
    b
}

impl Observer for Terminal {
    fn event(&self, e: Event<'_>) {
        let Ok(mut slot) = self.bar.lock() else { return };
        match e {
            Event::Message(text) => match slot.as_ref() {
                Some((_, b)) => b.println(text),
                None => eprintln!("{text}"),
            },
            Event::Progress {
                task,
                done,
                total,
                detail,
            } => {
                if slot.as_ref().is_none_or(|(t, _)| t != task) {
                    *slot = Some((task.to_string(), bar_for(task, total)));
                }
                if let Some((_, b)) = slot.as_ref() {
                    b.set_position(if task == "run" {
                        (done * 10.0) as u64
                    } else {
                        done as u64
                    });
                    b.set_message(detail.to_string());
                }
            }
            Event::Finished { task, ok } => {
                if let Some((t, b)) = slot.take() {
                    if t != task {
                        *slot = Some((t, b));
                    } else if ok {
                        b.finish_and_clear();
                    } else {
                        b.abandon();
                    }
                }
            }
        }
    }
}
