//! `report.html`: a run's report as pictures — time per keyframe by stage,
//! memory, and Gaussians over the run, plus the slowest kernels — in one
//! self-contained file (inline SVG and CSS; nothing is fetched).

use std::fmt::Write as _;

use anyhow::{anyhow, Result};
use latentam::{KeyframeReport, RunReport};
use plotters::prelude::*;

const PLOT_SIZE: (u32, u32) = (900, 320);
/// Rows of the kernel table.
const SLOWEST_KERNELS: usize = 15;

/// One line or band of a plot: a name and a value per keyframe.
struct Series {
    name: &'static str,
    values: Vec<f64>,
}

impl Series {
    fn of(name: &'static str, kfs: &[KeyframeReport], f: impl Fn(&KeyframeReport) -> f64) -> Self {
        Series {
            name,
            values: kfs.iter().map(f).collect(),
        }
    }
}

/// How a plot draws its series.
#[derive(Clone, Copy, PartialEq)]
enum Style {
    /// Lines, each on its own.
    Lines,
    /// Bands stacked in order: the top of the last is the sum of all.
    Stacked,
}

fn colour(i: usize) -> RGBColor {
    const COLOURS: [RGBColor; 7] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(127, 127, 127),
    ];
    COLOURS[i % COLOURS.len()]
}

/// An SVG plot of `series` against the keyframe number.
fn plot(title: &str, y_label: &str, series: &[Series], style: Style) -> Result<String> {
    let n = series.first().map_or(0, |s| s.values.len());
    // Stacked bands are drawn from their cumulative tops.
    let drawn: Vec<Vec<f64>> = match style {
        Style::Lines => series.iter().map(|s| s.values.clone()).collect(),
        Style::Stacked => {
            let mut sum = vec![0.0; n];
            series
                .iter()
                .map(|s| {
                    for (acc, v) in sum.iter_mut().zip(&s.values) {
                        *acc += v.max(0.0);
                    }
                    sum.clone()
                })
                .collect()
        }
    };
    let y_max = drawn
        .iter()
        .flatten()
        .cloned()
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max)
        .max(1e-9)
        * 1.08;
    let x_max = (n.max(2) - 1) as f64;
    let mut svg = String::new();
    {
        let err = |e: &dyn std::fmt::Display| anyhow!("drawing `{title}`: {e}");
        let root = SVGBackend::with_string(&mut svg, PLOT_SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..x_max, 0.0..y_max)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("keyframe")
            .x_label_formatter(&|x| {
                // Keyframes are whole numbers.
                if x.fract().abs() < 1e-9 {
                    format!("{x:.0}")
                } else {
                    String::new()
                }
            })
            .y_desc(y_label)
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(|e| err(&e))?;
        // Stacked: the tallest band first, so each lower one is drawn over it.
        let order: Vec<usize> = match style {
            Style::Lines => (0..series.len()).collect(),
            Style::Stacked => (0..series.len()).rev().collect(),
        };
        for i in order {
            let c = colour(i);
            let points = drawn[i].iter().enumerate().map(|(k, &v)| (k as f64, v));
            let legend =
                move |(x, y): (i32, i32)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], c.filled());
            match style {
                Style::Lines => chart
                    .draw_series(LineSeries::new(points, c.stroke_width(2)))
                    .map_err(|e| err(&e))?,
                Style::Stacked => chart
                    .draw_series(AreaSeries::new(points, 0.0, c.mix(0.85)).border_style(c))
                    .map_err(|e| err(&e))?,
            }
            .label(series[i].name)
            .legend(legend);
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .draw()
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(svg)
}

/// `text` with the characters HTML gives a meaning escaped.
fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

const MIB: f64 = 1024.0 * 1024.0;

/// The summary table's rows: what ran, how it ended, time and memory.
fn summary_rows(report: &RunReport, ending: String) -> [(&'static str, String); 11] {
    [
        ("run id", report.run_id.clone()),
        ("log", report.log.clone()),
        ("device", report.device.clone()),
        ("ending", ending),
        (
            "frames / keyframes",
            format!("{} / {}", report.frames, report.keyframes),
        ),
        (
            "wall time",
            format!("{:.1} s ({:.2} frames/s)", report.wall_s, report.fps),
        ),
        (
            "Gaussians in the map / resident",
            format!("{} / {}", report.gaussians, report.resident),
        ),
        (
            "peak GPU memory (budget)",
            format!(
                "{:.1} MiB ({:.1} MiB)",
                report.peak_gpu_bytes as f64 / MIB,
                report.gpu_budget as f64 / MIB
            ),
        ),
        (
            "peak CPU memory (map and history)",
            format!("{:.1} MiB", report.peak_cpu_bytes as f64 / MIB),
        ),
        (
            "mean time per keyframe",
            format!("{:.1} ms", report.ms_per_keyframe.total_ms),
        ),
        (
            "host waits per keyframe (mean / most; in Stage I + II)",
            format!(
                "{:.1} / {}; {:.1} / {}",
                report.host_waits_per_keyframe.mean,
                report.host_waits_per_keyframe.max,
                report.host_waits_per_keyframe.stage_one_and_two_mean,
                report.host_waits_per_keyframe.stage_one_and_two_max
            ),
        ),
    ]
}

/// Time by stage, memory and Gaussians after each keyframe, as SVG plots.
fn write_plots(html: &mut String, kfs: &[KeyframeReport]) -> Result<()> {
    if kfs.is_empty() {
        html.push_str("<p>No keyframe was mapped: there is nothing to plot.</p>\n");
    } else {
        let t = |k: &KeyframeReport| k.timings;
        let stages = [
            Series::of("dictionary (k-means)", kfs, |k| t(k).kmeans_ms),
            Series::of("insertion", kfs, |k| t(k).insertion_ms),
            Series::of("Stage I", kfs, |k| t(k).stage_one_ms),
            Series::of("Stage II and paging", kfs, |k| t(k).stage_two_ms),
            Series::of("pruning", kfs, |k| t(k).prune_ms),
            Series::of("other", kfs, |k| {
                let t = t(k);
                let parts =
                    t.kmeans_ms + t.insertion_ms + t.stage_one_ms + t.stage_two_ms + t.prune_ms;
                (t.total_ms - parts).max(0.0)
            }),
        ];
        let memory = [
            Series::of("GPU (allocated)", kfs, |k| k.gpu_bytes as f64 / MIB),
            Series::of("CPU (map and history)", kfs, |k| k.cpu_bytes as f64 / MIB),
        ];
        let gaussians = [
            Series::of("in the map", kfs, |k| k.gaussians as f64),
            Series::of("resident on the GPU", kfs, |k| k.resident as f64),
        ];
        for (title, svg) in [
            (
                "Time per keyframe, by stage",
                plot("Time per keyframe, by stage", "ms", &stages, Style::Stacked)?,
            ),
            (
                "Memory after each keyframe",
                plot("Memory after each keyframe", "MiB", &memory, Style::Lines)?,
            ),
            (
                "Gaussians after each keyframe",
                plot(
                    "Gaussians after each keyframe",
                    "Gaussians",
                    &gaussians,
                    Style::Lines,
                )?,
            ),
        ] {
            writeln!(
                html,
                "<figure aria-label=\"{}\">{svg}</figure>",
                escape(title)
            )?;
        }
    }
    Ok(())
}

/// The slowest kernels with their share of the run's wall time.
fn write_kernel_table(html: &mut String, report: &RunReport) -> Result<()> {
    let mut kernels: Vec<_> = report.kernels.iter().collect();
    kernels.sort_by(|a, b| b.1.total_ms.total_cmp(&a.1.total_ms));
    if kernels.is_empty() {
        html.push_str("<p>No kernel was timed (the device has no timestamps).</p>\n");
    } else {
        let wall_ms = (report.wall_s * 1e3).max(1e-9);
        html.push_str(
            "<h2>Slowest kernels</h2>\n<table>\n<tr><th>kernel</th><th>dispatches</th>\
             <th>total ms</th><th>mean ms</th><th>max ms</th><th>share of wall time</th></tr>\n",
        );
        for (name, k) in kernels.iter().take(SLOWEST_KERNELS) {
            writeln!(
                html,
                "<tr><td>{}</td><td>{}</td><td>{:.1}</td><td>{:.3}</td><td>{:.3}</td><td>{:.1} %</td></tr>",
                escape(name),
                k.count,
                k.total_ms,
                k.mean_ms,
                k.max_ms,
                100.0 * k.total_ms / wall_ms
            )?;
        }
        html.push_str("</table>\n");
    }
    Ok(())
}

/// Writes `report.html` for `report` into the run folder (or its staging
/// folder) `dir`, whole or not at all.
pub fn write_report_html(dir: &std::path::Path, report: &RunReport) -> latentam::Result<()> {
    let path = dir.join("report.html");
    let html = report_html(report).map_err(|e| latentam::Error::Io {
        path: path.clone(),
        source: std::io::Error::other(format!("{e:#}")),
    })?;
    latentam::files::write_bytes_atomically(&path, html.as_bytes())
}

/// The whole page for `report`.
pub fn report_html(report: &RunReport) -> Result<String> {
    let mut html = String::new();
    let ending = serde_json::to_value(&report.ending)?;
    let ending = ending
        .as_str()
        .map_or_else(|| ending.to_string(), str::to_string);
    write!(
        html,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>latentam run {id}</title><style>\
         body{{font-family:sans-serif;max-width:940px;margin:2em auto;color:#222}}\
         table{{border-collapse:collapse;margin:1em 0}}\
         td,th{{padding:2px 10px;border-bottom:1px solid #ddd;text-align:right}}\
         td:first-child,th:first-child{{text-align:left}}\
         figure{{margin:1.5em 0}}</style></head><body>\n\
         <h1>latentam run</h1>\n<table>\n",
        id = escape(&report.run_id)
    )?;
    let rows = summary_rows(report, ending);
    for (k, v) in rows {
        writeln!(
            html,
            "<tr><th>{}</th><td>{}</td></tr>",
            escape(k),
            escape(&v)
        )?;
    }
    html.push_str("</table>\n");

    write_plots(&mut html, &report.keyframe_reports)?;

    write_kernel_table(&mut html, report)?;
    html.push_str("</body></html>\n");
    Ok(html)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_what_html_would_read_as_markup() {
        assert_eq!(
            escape("<a href=\"x\">&'</a>"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;&lt;/a&gt;"
        );
    }

    #[test]
    fn stacked_plot_is_an_svg_with_one_band_per_series() {
        let series = [
            Series {
                name: "a",
                values: vec![1.0, 2.0, 3.0],
            },
            Series {
                name: "b",
                values: vec![2.0, 2.0, 2.0],
            },
        ];
        let svg = plot("t", "ms", &series, Style::Stacked).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..40]);
        assert!(
            svg.contains(">\na\n</text>") && svg.contains(">\nb\n</text>"),
            "{svg}"
        );
        assert_eq!(svg.matches("<polygon").count(), 2, "{svg}");
    }
}
