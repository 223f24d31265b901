//! The live view's flags (`--live` and its settings), shared by the
//! commands that map.

use std::net::SocketAddr;
use std::time::Duration;

use anyhow::{bail, Result};
use latentam::frames::Vocabulary;
use latentam::view::{ViewOptions, ViewWord};

#[derive(clap::Args, Clone, Debug)]
pub struct LiveViewArgs {
    /// Serve a live view of the map over the Foxglove WebSocket protocol
    /// while mapping: in Foxglove, "Open connection" to ws://ADDR:PORT.
    /// Without a value: 127.0.0.1:8765 (this machine only); 0.0.0.0:8765
    /// serves every interface.
    #[arg(long, value_name = "ADDR:PORT", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub live: Option<SocketAddr>,
    /// Most points in a live map cloud (17 bytes each as sent): a
    /// larger map is shown by an even subset.
    #[arg(long, value_name = "N", default_value_t = 100_000, requires = "live")]
    pub live_points: usize,
    /// Least seconds between two publications of the live map.
    #[arg(long, value_name = "SECONDS", default_value_t = 1.0, requires = "live")]
    pub live_every: f64,
    /// Width of the map rendered from the last keyframe's camera for the
    /// live view, pixels (0: none).
    #[arg(long, value_name = "PIXELS", default_value_t = 320, requires = "live")]
    pub live_render_width: u32,
    /// Least seconds between two renders: a render pauses mapping for its
    /// time (about a millisecond on a discrete GPU, a few hundred on a
    /// CPU driver).
    #[arg(long, value_name = "SECONDS", default_value_t = 5.0, requires = "live")]
    pub live_render_every: f64,
    /// Vocabulary words (of the log's vocabulary) whose relevance clouds
    /// the live view publishes, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "WORD,...",
        requires = "live"
    )]
    pub live_words: Vec<String>,
}

impl LiveViewArgs {
    /// Whether a live view was asked for; checks the settings (and that
    /// the address can be listened on) before any mapping starts.
    pub fn check(&self) -> Result<Option<SocketAddr>> {
        let Some(addr) = self.live else {
            return Ok(None);
        };
        for (flag, seconds) in [
            ("--live-every", self.live_every),
            ("--live-render-every", self.live_render_every),
        ] {
            if !(seconds >= 0.0 && seconds.is_finite()) {
                bail!("{flag} must be a number of seconds, 0 or more");
            }
        }
        if self.live_points == 0 {
            bail!("--live-points must be at least 1");
        }
        // Said now rather than after the device and the log are opened.
        if let Err(e) = std::net::TcpListener::bind(addr) {
            bail!("--live {addr}: cannot listen there: {e}");
        }
        Ok(Some(addr))
    }

    /// The view's options, with the relevance words taken from
    /// `vocabulary` (errors for a word it lacks, or words without one).
    pub fn options(&self, vocabulary: Option<&Vocabulary>) -> Result<Option<ViewOptions>> {
        let Some(listen) = self.live else {
            return Ok(None);
        };
        let words = match (vocabulary, self.live_words.is_empty()) {
            (_, true) => Vec::new(),
            (Some(v), false) => ViewWord::from_vocabulary(v, &self.live_words, 0.1)?,
            (None, false) => bail!("--live-words: the log has no vocabulary"),
        };
        Ok(Some(ViewOptions {
            listen,
            point_budget: self.live_points,
            min_interval: Duration::from_secs_f64(self.live_every),
            render_width: self.live_render_width,
            render_interval: Duration::from_secs_f64(self.live_render_every),
            words,
            ..ViewOptions::default()
        }))
    }
}
