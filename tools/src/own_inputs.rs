//! A command never writes over what it reads: every output path is
//! resolved (links followed, `..` and relative parts removed, whether or
//! not the file exists yet) and compared with the command's inputs before
//! any work, so `eval DIR LOG --json LOG` or `query DIR --out
//! DIR/state.latentam` fail at once instead of destroying the log or the map.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use latentam::runs::RUN_FOLDER_FILES;

/// Something a command reads.
#[derive(Clone, Copy, Debug)]
pub enum Input<'a> {
    /// A file (a log, an embedding, a vocabulary log).
    File(&'a Path),
    /// A run folder: its files are read (the heat map `query` writes into
    /// it by default is the one a command may replace).
    RunFolder(&'a Path),
}

/// `path` made absolute with links resolved: the file itself when it
/// exists, else its resolved parent joined with its name.
fn resolved(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = std::fs::canonicalize(path) {
        return Some(p);
    }
    let absolute = std::path::absolute(path).ok()?;
    let name = absolute.file_name()?;
    let parent = std::fs::canonicalize(absolute.parent()?).ok()?;
    Some(parent.join(name))
}

/// Errors when any of `outputs` (flag name, path) would write over one of
/// `inputs`.
pub fn refuse_overwriting_inputs(inputs: &[Input], outputs: &[(&str, &Path)]) -> Result<()> {
    for &(flag, output) in outputs {
        let Some(out) = resolved(output) else {
            continue;
        };
        for input in inputs {
            let clash = match *input {
                Input::File(file) => resolved(file).is_some_and(|f| f == out),
                Input::RunFolder(dir) => resolved(dir).is_some_and(|d| {
                    out == d
                        || RUN_FOLDER_FILES
                            .iter()
                            .filter(|f| **f != "heatmap.ply")
                            .any(|f| out == d.join(f))
                }),
            };
            if clash {
                let what = match input {
                    Input::File(f) => format!("{}, an input of this command", f.display()),
                    Input::RunFolder(d) => {
                        format!(
                            "a file of the run folder {} this command reads",
                            d.display()
                        )
                    }
                };
                bail!(
                    "{flag} {} would write over {what}; choose another path",
                    output.display()
                );
            }
        }
    }
    Ok(())
}

/// Errors when one of `inputs` (flag name, path) lies inside `run`, a run
/// folder the command replaces whole: the input would go with it (a log
/// or a configuration kept in a run folder, even the run's own
/// `config.toml` edited by hand); and when `run` lies inside an input
/// folder (a rosbag2 folder), which it would change.
pub fn refuse_inputs_inside(run: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    let Some(run_dir) = resolved(run) else {
        return Ok(());
    };
    for &(what, input) in inputs {
        let Some(input_path) = resolved(input) else {
            continue;
        };
        if input_path.starts_with(&run_dir) {
            bail!(
                "{what} {} lies inside {}, the run folder this command replaces whole, so it \
                 would be lost: move it out of the folder or choose another --out",
                input.display(),
                run.display()
            );
        }
        // A rosbag2 folder holding the run: the bag would no longer read
        // as one (a folder it does not know).
        if input_path.is_dir() && run_dir.starts_with(&input_path) {
            bail!(
                "--out {} lies inside {what} {}, a folder this command reads: choose an --out \
                 outside it",
                run.display(),
                input.display()
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_that_resolve_to_an_input_are_refused() {
        let dir = std::env::temp_dir().join(format!("latentam-own-inputs-{}", std::process::id()));
        let run = dir.join("run");
        std::fs::create_dir_all(&run).unwrap();
        let log = dir.join("scene.mcap");
        std::fs::write(&log, b"log").unwrap();
        std::fs::write(run.join("state.latentam"), b"state").unwrap();
        let inputs = [Input::RunFolder(&run), Input::File(&log)];
        let check = |p: &Path| refuse_overwriting_inputs(&inputs, &[("--out", p)]);
        // The log by another spelling, and through a link.
        assert!(check(&dir.join("run/../scene.mcap")).is_err());
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(&log, dir.join("alias.mcap")).unwrap();
            assert!(check(&dir.join("alias.mcap")).is_err());
        }
        // The run's own files, existing or not, and the folder itself.
        assert!(check(&run.join("state.latentam")).is_err());
        assert!(check(&run.join("decoder.safetensors")).is_err());
        let e = check(&run).unwrap_err().to_string();
        assert!(
            e.contains("run folder") && e.contains("choose another path"),
            "{e}"
        );
        // The heat map beside them, and anything elsewhere, are fine.
        assert!(check(&run.join("heatmap.ply")).is_ok());
        assert!(check(&dir.join("eval.json")).is_ok());
        assert!(check(&dir.join("missing/eval.json")).is_ok());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
