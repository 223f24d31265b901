//! `latentam render`: pictures of a mapped run from one camera — the
//! rendered colour, depth and, for a query, relevance — from a pose or
//! from a frame of a log (whose input image is written beside them).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};
use glam::{DAffine3, DQuat, DVec3};
use latentam::frames::{Frame, McapFrames};
use latentam::{Mapper, RenderedView, Viewpoint};
use latentam_cli::progress::Stages;

use crate::pictures::{self, heat_picture, range_of, Picture, COVERED_ALPHA};
use crate::query_args::{queryable_dim, Query, QueryArgs};

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("camera").required(true).args(["view", "frame"])))]
pub struct Args {
    /// Run folder written by `latentam map`.
    pub dir: PathBuf,
    /// Log whose frame --frame renders (its pose and intrinsics); it also
    /// holds the vocabulary for --name unless --vocabulary names another.
    pub log: Option<PathBuf>,
    /// Render the view of the log's N-th frame (0-based, counting the
    /// frames the log assembles, as `eval` does) and write its input image
    /// and depth beside the renders.
    #[arg(long, value_name = "N", requires = "log")]
    pub frame: Option<u64>,
    /// Render from this camera pose, `tx,ty,tz,qx,qy,qz,qw`
    /// (camera-to-world, as in trajectory.txt), with the intrinsics of the
    /// map's last keyframe.
    #[arg(long, value_name = "POSE", allow_hyphen_values = true)]
    pub view: Option<String>,
    /// Prefix of the pictures: PREFIX-color.png and PREFIX-depth.png, with
    /// a query PREFIX-relevance.png, with --frame PREFIX-input.png and
    /// PREFIX-input-depth.png.
    #[arg(long, value_name = "PREFIX")]
    pub out: PathBuf,
    #[command(flatten)]
    pub query: QueryArgs,
    #[command(flatten)]
    pub input: crate::input_args::InputArgs,
}

/// A camera pose `tx,ty,tz,qx,qy,qz,qw` (camera-to-world) as given to
/// `--view`.
pub fn parse_pose(s: &str) -> Result<DAffine3> {
    let v: Vec<f64> = s
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|p| !p.is_empty())
        .map(|p| p.parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--view {s:?}: not numbers"))?;
    if v.len() != 7 || v.iter().any(|x| !x.is_finite()) {
        bail!("--view {s:?}: expected 7 finite numbers tx,ty,tz,qx,qy,qz,qw");
    }
    let q = DQuat::from_xyzw(v[3], v[4], v[5], v[6]);
    if (q.length() - 1.0).abs() > 1e-3 {
        bail!(
            "--view {s:?}: the quaternion has norm {:.4}, not 1",
            q.length()
        );
    }
    Ok(DAffine3::from_rotation_translation(
        q.normalize(),
        DVec3::new(v[0], v[1], v[2]),
    ))
}

/// The relevance of every pixel of `view` as a picture (black where the
/// map covers the pixel too little), with the range its colours span.
pub fn relevance_picture(
    mapper: &mut Mapper,
    query: &Query,
    view: &RenderedView,
) -> Result<(Picture, (f32, f32))> {
    let rel = query.score_view(mapper, view)?;
    let covered = |i: usize| view.alpha[i] >= COVERED_ALPHA;
    let range = query.colour_range(&rel, covered);
    Ok((
        heat_picture(view.width, view.height, &rel, range, covered),
        range,
    ))
}

/// Where the view comes from.
pub enum ViewSource<'a> {
    Pose(DAffine3),
    Frame(&'a Frame),
}

/// Every picture of one view.
pub struct Pictures {
    pub colour: Picture,
    pub depth: Picture,
    /// The metres the depth colours span (near: blue, far: red).
    pub depth_range: (f32, f32),
    /// With a query: the picture and the relevance its colours span.
    pub relevance: Option<(Picture, (f32, f32))>,
    /// With a frame: its colour and depth images.
    pub input: Option<(Picture, Picture)>,
    /// Gaussians rendered.
    pub gaussians: usize,
}

/// Renders `mapper`'s map from `source` into pictures. Input and rendered
/// depth share one colour range (the input's, when there is one) so they
/// compare at a glance.
pub fn render_pictures(
    mapper: &mut Mapper,
    source: ViewSource<'_>,
    query: Option<&Query>,
) -> Result<Pictures> {
    let (view, gaussians) = match source {
        ViewSource::Pose(pose) => mapper.render(Viewpoint::Pose(pose))?,
        ViewSource::Frame(frame) => mapper.render(frame)?,
    };
    let rendered_depth = pictures::rendered_depth_m(&view);
    let input_depth = match source {
        ViewSource::Frame(f) => Some(pictures::input_depth_m(f)),
        ViewSource::Pose(_) => None,
    };
    let depth_range = input_depth
        .as_deref()
        .and_then(|d| range_of(d, |_| true))
        .or_else(|| range_of(&rendered_depth, |_| true))
        .unwrap_or((0.0, 1.0));
    let all = |_| true;
    let depth = heat_picture(view.width, view.height, &rendered_depth, depth_range, all);
    let input = match source {
        ViewSource::Frame(f) => {
            let d = input_depth.as_deref().expect("a frame's depth, above");
            Some((
                pictures::input_colour(f),
                heat_picture(f.depth.width, f.depth.height, d, depth_range, all),
            ))
        }
        ViewSource::Pose(_) => None,
    };
    let relevance = query
        .map(|q| relevance_picture(mapper, q, &view))
        .transpose()?;
    Ok(Pictures {
        colour: pictures::rendered_colour(&view),
        depth,
        depth_range,
        relevance,
        input,
        gaussians,
    })
}

/// The `n`-th frame (0-based) `frames` assembles.
pub fn nth_frame(frames: McapFrames, n: u64, log: &Path) -> Result<Frame> {
    let mut seen = 0u64;
    for frame in frames {
        let frame = frame.with_context(|| format!("reading {}", log.display()))?;
        if seen == n {
            return Ok(frame);
        }
        seen += 1;
    }
    bail!(
        "{} has {seen} frame{}: there is no frame {n} (frames count from 0)",
        log.display(),
        if seen == 1 { "" } else { "s" }
    )
}

/// `PREFIX-suffix.png`.
fn path_of(prefix: &Path, suffix: &str) -> PathBuf {
    let mut name = prefix.file_name().unwrap_or_default().to_os_string();
    name.push(format!("-{suffix}.png"));
    prefix.with_file_name(name)
}

pub fn run(args: Args) -> Result<()> {
    let pose = args.view.as_deref().map(parse_pose).transpose()?;
    if args.out.file_name().is_none() {
        bail!(
            "--out {}: give a file name prefix, e.g. views/kitchen",
            args.out.display()
        );
    }
    let mut inputs = vec![crate::own_inputs::Input::RunFolder(&args.dir)];
    inputs.extend(args.log.as_deref().map(crate::own_inputs::Input::File));
    inputs.extend(
        args.query
            .embedding
            .as_deref()
            .map(crate::own_inputs::Input::File),
    );
    inputs.extend(
        args.query
            .vocabulary
            .as_deref()
            .map(crate::own_inputs::Input::File),
    );
    let pictures: Vec<PathBuf> = ["color", "depth", "relevance", "input", "input-depth"]
        .iter()
        .map(|s| path_of(&args.out, s))
        .collect();
    let outputs: Vec<(&str, &Path)> = pictures.iter().map(|p| ("--out", p.as_path())).collect();
    crate::own_inputs::refuse_overwriting_inputs(&inputs, &outputs)?;
    let stages = Stages::new("render");
    let (ctx, mut mapper) = crate::loaded_map::load_nonempty_map(&stages, &args.dir, "render")?;
    // Rendered views of any size; the mapping budget is not meant for it.
    ctx.set_memory_budget(None);
    let query = if args.query.given() {
        let dim = queryable_dim(&mapper, &args.dir)?;
        let topic = args
            .input
            .vocabulary_topic
            .as_deref()
            .unwrap_or("/vocabulary");
        args.query
            .resolve(&mapper, dim, args.log.as_deref(), topic)?
    } else {
        None
    };
    let frame = match (args.frame, &args.log) {
        (Some(n), Some(log)) => {
            stages.start(format_args!("reading frame {n} of {}", log.display()));
            let frames = McapFrames::open(log, args.input.assembly()?)
                .with_context(|| format!("opening {}", log.display()))?;
            Some(nth_frame(frames, n, log)?)
        }
        _ => None,
    };
    let source = match (&frame, pose) {
        (Some(f), _) => ViewSource::Frame(f),
        (None, Some(p)) => ViewSource::Pose(p),
        // clap: --view or --frame (which requires LOG).
        (None, None) => unreachable!("clap requires --view or --frame"),
    };
    stages.start("rendering");
    let pictures = render_pictures(&mut mapper, source, query.as_ref())?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut written = vec![
        (path_of(&args.out, "color"), &pictures.colour, String::new()),
        (
            path_of(&args.out, "depth"),
            &pictures.depth,
            format!(
                "  ({:.2} m blue to {:.2} m red)",
                pictures.depth_range.0, pictures.depth_range.1
            ),
        ),
    ];
    if let (Some((p, (lo, hi))), Some(q)) = (&pictures.relevance, &query) {
        written.push((
            path_of(&args.out, "relevance"),
            p,
            format!("  ({} from {lo:.3} blue to {hi:.3} red)", q.what),
        ));
    }
    if let Some((colour, depth)) = &pictures.input {
        written.push((path_of(&args.out, "input"), colour, String::new()));
        written.push((path_of(&args.out, "input-depth"), depth, String::new()));
    }
    for (path, picture, _) in &written {
        picture.write_png(path)?;
    }
    println!(
        "rendered {} Gaussians at {}×{}:",
        pictures.gaussians, pictures.colour.width, pictures.colour.height
    );
    for (path, _, note) in &written {
        println!("  {}{note}", path.display());
    }
    Ok(())
}
