//! Text from files and the command line, made safe to print: a log's
//! vocabulary names, a run id or a configuration value could carry
//! terminal escape sequences (clearing the screen, forging an `error:`
//! line) or megabytes of text.

/// Longest line shown whole; longer ones are cut with a note of how much
/// was left out.
pub const MAX_SHOWN_LINE: usize = 400;

/// `text` with every control character except newline and tab written as
/// an escape (`\u{1b}`), and every line cut after [`MAX_SHOWN_LINE`]
/// characters.
///
/// ```
/// use latentam_base::text::shown;
/// assert_eq!(shown("chair\u{1b}[2J"), "chair\\u{1b}[2J");
/// assert!(shown(&"x".repeat(10_000)).ends_with("(9600 more bytes)"));
/// ```
pub fn shown(text: &str) -> String {
    let mut out = String::with_capacity(text.len().min(4 * MAX_SHOWN_LINE));
    for (i, line) in text.split('\n').enumerate() {
        if i > 0 {
            out.push('\n');
        }
        for (chars, (at, c)) in line.char_indices().enumerate() {
            if chars == MAX_SHOWN_LINE {
                out.push_str(&format!("… ({} more bytes)", line.len() - at));
                break;
            }
            if c.is_control() && c != '\t' {
                out.extend(c.escape_unicode());
            } else {
                out.push(c);
            }
        }
    }
    out
}

/// [`shown`] for a path: a file name may hold any byte but `/` and NUL,
/// escape sequences included.
///
/// ```
/// use latentam_base::text::shown_path;
/// assert_eq!(shown_path("run\u{1b}[2J".as_ref()), "run\\u{1b}[2J");
/// ```
pub fn shown_path(path: &std::path::Path) -> String {
    shown(&path.display().to_string())
}

/// An error's message followed by each of its causes that it does not
/// already quote, joined by `: `. A wrapper's own text ("I/O error from
/// writing") often leaves out what the user can act on ("File too
/// large"), which only its source says.
///
/// ```
/// use latentam_base::text::with_causes;
/// let e = latentam_base::Error::Io {
///     path: "map.ply".into(),
///     source: std::io::Error::other("disk full"),
/// };
/// assert_eq!(with_causes(&e), "map.ply: disk full");
/// ```
pub fn with_causes(error: &dyn std::error::Error) -> String {
    let mut message = error.to_string();
    let mut cause = error.source();
    while let Some(c) = cause {
        let text = c.to_string();
        if !message.contains(&text) {
            message = format!("{message}: {text}");
        }
        cause = c.source();
    }
    message
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_and_long_lines_are_defused() {
        // An escape sequence that would clear the screen, a carriage
        // return that would overwrite the line, a bell.
        assert_eq!(shown("a\u{1b}[2Jb\rc\u{7}"), "a\\u{1b}[2Jb\\u{d}c\\u{7}");
        // Newlines and tabs stay; other text is untouched.
        assert_eq!(shown("wall\tfloor\nchair ü"), "wall\tfloor\nchair ü");
        let long = format!("{}\nshort", "é".repeat(1000));
        let s = shown(&long);
        assert!(s.starts_with(&"é".repeat(MAX_SHOWN_LINE)));
        assert!(s.contains(&format!("({} more bytes)", 2 * (1000 - MAX_SHOWN_LINE))));
        assert!(s.ends_with("\nshort"));
    }
}
