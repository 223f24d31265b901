//! What the library reports through `log` (a folder restored after an
//! interrupted save, a log read linearly for want of an index, a
//! validation message from the driver) reaches the user on stderr.
//!
//! Warnings and errors are shown by default, `-v` adds progress notes
//! (info), `-vv` debug detail; `RUST_LOG` (e.g. `RUST_LOG=latentam_io=debug`)
//! overrides both.

use std::io::{IsTerminal, Write};

/// Installs the logger for this process; `verbose` counts `-v` flags.
pub fn install(verbose: u8) {
    let level = match verbose {
        0 => "warn",
        1 => "info",
        2 => "debug",
        _ => "trace",
    };
    // On a terminal a status line may be drawn in place (`progress.rs`):
    // clear it first so the message starts at the left edge; the status
    // line is redrawn on its next update.
    let clear = if std::io::stderr().is_terminal() {
        "\r\x1b[K"
    } else {
        ""
    };
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(level))
        .format(move |out, record| {
            let level = match record.level() {
                log::Level::Error => "error",
                log::Level::Warn => "warning",
                log::Level::Info => "note",
                log::Level::Debug => "debug",
                log::Level::Trace => "trace",
            };
            if record.level() <= log::Level::Info {
                writeln!(out, "{clear}{level}: {}", record.args())
            } else {
                writeln!(
                    out,
                    "{clear}{level} [{}]: {}",
                    record.target(),
                    record.args()
                )
            }
        })
        .init();
}
