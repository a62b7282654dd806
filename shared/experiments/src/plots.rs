//! Figures a researcher looks at, as PNG files: training curves (Fig. 3),
//! curriculum snapshots (Fig. 4), validation trajectories (Fig. 5) and
//! multi-run comparisons (mean ± std over seeds).
//!
//! Text is drawn with DejaVu Sans from the system (`fonts-dejavu-core`, installed
//! by `deploy/setup_system.sh`); maps come from `pednav_sim::draw`.

use std::path::Path;
use std::sync::OnceLock;

use image::RgbImage;
use pednav_curriculum::{Curriculum, CurriculumConfig, ServiceState, classify_region};
use pednav_sim::Scene;
use pednav_sim::draw::draw_map;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::{ExperimentError, Result};
use crate::table::EpisodeResult;

const FONT_PATHS: [&str; 2] =
    ["/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf", "/usr/share/fonts/TTF/DejaVuSans.ttf"];

/// Register the font plotters draws text with (once per process).
pub fn init_font() -> Result<()> {
    static DONE: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        let bytes = FONT_PATHS.iter().find_map(|p| std::fs::read(p).ok()).ok_or_else(|| {
            format!("no DejaVu Sans font at {FONT_PATHS:?}: install `fonts-dejavu-core` (deploy/setup_system.sh does)")
        })?;
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .map_err(|_| "invalid font file".to_string())
    })
    .clone()
    .map_err(ExperimentError::Plot)
}

fn plot_err(e: impl std::fmt::Display) -> ExperimentError {
    ExperimentError::Plot(e.to_string())
}

fn save(buf: Vec<u8>, w: u32, h: u32, path: &Path) -> Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| ExperimentError::file(dir, e))?;
    }
    let img = RgbImage::from_raw(w, h, buf).expect("buffer matches the size");
    img.save(path).map_err(|e| ExperimentError::file(path, e))
}

/// A curve: points, optional ±band, colour, label.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend label.
    pub label: String,
    /// (x, y) points.
    pub points: Vec<(f64, f64)>,
    /// Half-width of a shaded band around each point (same length as `points`), e.g. a std.
    pub band: Option<Vec<f64>>,
    /// Line colour.
    pub colour: RGBColor,
    /// Draw as faint dots instead of a line.
    pub dots: bool,
}

/// Palette for curves and trajectories.
pub const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

/// One chart with curves and labelled horizontal reference lines, as a PNG.
pub fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    hlines: &[(String, f64)],
) -> Result<()> {
    init_font()?;
    let (w, h) = (1000u32, 620u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        draw_chart(
            &root,
            &Panel { title: title.into(), x_label: x_label.into(), y_label: y_label.into(), series: series.to_vec() },
            hlines,
        )?;
        root.present().map_err(plot_err)?;
    }
    save(buf, w, h, path)
}

/// One chart of a multi-panel figure.
#[derive(Debug, Clone)]
pub struct Panel {
    /// The panel's caption.
    pub title: String,
    /// Horizontal axis label.
    pub x_label: String,
    /// Vertical axis label.
    pub y_label: String,
    /// Its curves.
    pub series: Vec<Series>,
}

/// Several charts in a grid of `columns` columns under one title, as a PNG.
pub fn panel_chart(path: &Path, title: &str, panels: &[Panel], columns: usize) -> Result<()> {
    init_font()?;
    let columns = columns.clamp(1, panels.len().max(1));
    let rows = panels.len().div_ceil(columns).max(1);
    let (w, h) = (620 * columns as u32, 420 * rows as u32 + 50);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let body = root.titled(title, ("sans-serif", 26)).map_err(plot_err)?;
        for (area, panel) in body.split_evenly((rows, columns)).iter().zip(panels) {
            draw_chart(area, panel, &[])?;
        }
        root.present().map_err(plot_err)?;
    }
    save(buf, w, h, path)
}

/// Draw `panel` (and labelled horizontal lines) into `area`.
fn draw_chart(area: &DrawingArea<BitMapBackend<'_>, Shift>, panel: &Panel, hlines: &[(String, f64)]) -> Result<()> {
    let (title, x_label, y_label, series) = (&panel.title, &panel.x_label, &panel.y_label, &panel.series);
    let all = series.iter().flat_map(|s| {
        s.points.iter().enumerate().flat_map(move |(i, p)| {
            let b = s.band.as_ref().map_or(0.0, |b| b[i]);
            [(p.0, p.1 - b), (p.0, p.1 + b)]
        })
    });
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (x, y) in all.chain(hlines.iter().map(|l| (f64::NAN, l.1))) {
        if x.is_finite() {
            x0 = x0.min(x);
            x1 = x1.max(x);
        }
        if y.is_finite() {
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
    }
    if x0 > x1 {
        (x0, x1) = (0.0, 1.0);
    }
    if y0 > y1 {
        (y0, y1) = (0.0, 1.0);
    }
    let pad = ((y1 - y0) * 0.05).max(1e-3);
    let x1 = if x1 > x0 { x1 } else { x0 + 1.0 };
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 24))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(65)
        .build_cartesian_2d(x0..x1, (y0 - pad)..(y1 + pad))
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_labels(7)
        .x_label_formatter(&|v| short_number(*v))
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(plot_err)?;
    for s in series {
        if let Some(band) = &s.band {
            let upper = s.points.iter().zip(band).map(|(p, b)| (p.0, p.1 + b));
            let lower: Vec<_> = s.points.iter().zip(band).map(|(p, b)| (p.0, p.1 - b)).collect();
            let poly: Vec<(f64, f64)> = upper.chain(lower.into_iter().rev()).collect();
            chart.draw_series(std::iter::once(Polygon::new(poly, s.colour.mix(0.2).filled()))).map_err(plot_err)?;
        }
        if s.dots {
            chart
                .draw_series(s.points.iter().map(|&p| Circle::new(p, 2, s.colour.mix(0.25).filled())))
                .map_err(plot_err)?;
        } else {
            let c = s.colour;
            chart
                .draw_series(LineSeries::new(s.points.iter().copied(), c.stroke_width(2)))
                .map_err(plot_err)?
                .label(s.label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        }
    }
    for (i, (label, y)) in hlines.iter().enumerate() {
        let c = PALETTE[(3 + i) % PALETTE.len()];
        let style = ShapeStyle { color: c.mix(0.9), filled: false, stroke_width: 2 };
        chart
            .draw_series(DashedLineSeries::new([(x0, *y), (x1, *y)], 6 + i as u32 * 2, 4, style))
            .map_err(plot_err)?
            .label(label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(plot_err)?;
    Ok(())
}

/// A run's `metrics/learner.csv`: its column names and rows (a value that is absent
/// or not a number reads as NaN); an error when the file is missing or has no rows.
pub fn learner_log(run: &Path) -> Result<(Vec<String>, Vec<Vec<f64>>)> {
    let path = pednav_runtime::RunDir::new(run).metrics_csv("learner");
    let text = std::fs::read_to_string(&path).map_err(|e| {
        ExperimentError::file(&path, format!("no learner log (the learner writes it during a run): {e}"))
    })?;
    let mut lines = text.lines();
    let header: Vec<String> =
        lines.next().ok_or_else(|| ExperimentError::file(&path, "empty"))?.split(',').map(str::to_string).collect();
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse::<f64>().unwrap_or(f64::NAN)).collect::<Vec<f64>>())
        .filter(|r| r.len() == header.len())
        .collect();
    if rows.is_empty() {
        return Err(ExperimentError::file(&path, "no rows yet"));
    }
    Ok((header, rows))
}

/// An axis label: 1,500 → "1.5k", 200,000 → "200k", 3,000,000 → "3M", 0.25 → "0.25".
pub fn short_number(v: f64) -> String {
    let trim = |s: String| if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s };
    match v.abs() {
        a if a >= 1e6 => format!("{}M", trim(format!("{:.2}", v / 1e6))),
        a if a >= 1e3 => format!("{}k", trim(format!("{:.1}", v / 1e3))),
        _ => trim(format!("{v:.2}")),
    }
}

/// Centred moving average over `window` points (shorter at the ends).
pub fn moving_average(y: &[f64], window: usize) -> Vec<f64> {
    let half = window.max(1) / 2;
    (0..y.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(half), (i + half + 1).min(y.len()));
            y[a..b].iter().sum::<f64>() / (b - a) as f64
        })
        .collect()
}

/// Write text onto an RGB image (labels of montages and maps).
fn annotate(img: &mut RgbImage, lines: &[(i32, i32, String, u32)]) -> Result<()> {
    init_font()?;
    let (w, h) = img.dimensions();
    let mut buf = std::mem::take(img).into_raw();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        for (x, y, text, size) in lines {
            root.draw_text(text, &("sans-serif", *size).into_text_style(&root).color(&BLACK), (*x, *y))
                .map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    *img = RgbImage::from_raw(w, h, buf).expect("same size");
    Ok(())
}

/// Fig. 5: every episode's trajectory over the map, coloured by start point.
pub fn trajectories(scene: &Scene, results: &[EpisodeResult], title: &str, path: &Path) -> Result<()> {
    let mut canvas = draw_map(scene, &pednav_sim::RegionMap::new(scene), 10.0);
    for r in results {
        let c = PALETTE[r.point as usize % PALETTE.len()];
        let pts: Vec<(f32, f32)> = r.trajectory.iter().map(|p| (p[0], p[1])).collect();
        canvas.polyline(&pts, 1.0, [c.0, c.1, c.2]);
    }
    for r in results {
        if let Some(s) = r.trajectory.first() {
            canvas.disc(s[0], s[1], 3.0, [0, 0, 0]);
        }
    }
    let mut img = canvas.image;
    let n_ok = results.iter().filter(|r| r.success).count();
    annotate(&mut img, &[(8, 6, format!("{title} — {} episodes, {n_ok} reached the goal", results.len()), 18)])?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| ExperimentError::file(dir, e))?;
    }
    img.save(path).map_err(|e| ExperimentError::file(path, e))
}

/// Fig. 4 over time: the classification of up to `max` snapshots (evenly chosen,
/// oldest first) in one montage.
pub fn curriculum_snapshots(
    scene: &Scene,
    cfg: &CurriculumConfig,
    (dt, seed): (f32, u64),
    snapshots: &[std::path::PathBuf],
    max: usize,
    path: &Path,
) -> Result<usize> {
    if snapshots.is_empty() {
        return Err(ExperimentError::Plot("no curriculum snapshots to draw".into()));
    }
    let n = snapshots.len().min(max.max(1));
    let chosen: Vec<&std::path::PathBuf> = (0..n)
        .map(|i| &snapshots[if n == 1 { snapshots.len() - 1 } else { i * (snapshots.len() - 1) / (n - 1) }])
        .collect();
    let mut tiles = Vec::new();
    for p in &chosen {
        let state = ServiceState::load(p).map_err(|e| ExperimentError::file(p, e))?;
        let mut c = Curriculum::from_saved(cfg.clone(), scene.clone(), dt, seed, &state.curriculum)
            .map_err(|e| ExperimentError::file(p, e))?;
        let Some(class) = classify_region(&mut c, scene, cfg, 0.5).map_err(|e| ExperimentError::file(p, e))? else {
            return Err(ExperimentError::Plot("the fixed-start variant has no classification".into()));
        };
        let mut img = class.draw(scene, 6.0).image;
        let label = format!(
            "episode {}, {:.2}M steps, {}, μ {:.1} σ {:.1}",
            state.curriculum.episodes,
            state.decision_steps as f64 / 1e6,
            if class.acl { "ACL" } else { "first task" },
            class.fit.mu,
            class.fit.sigma
        );
        annotate(&mut img, &[(6, 4, label, 15)])?;
        tiles.push(img);
    }
    let cols = tiles.len().min(3) as u32;
    let rows = (tiles.len() as u32).div_ceil(cols);
    let (tw, th) = tiles[0].dimensions();
    let mut montage = RgbImage::from_pixel(cols * tw, rows * th + 30, image::Rgb([255, 255, 255]));
    for (i, t) in tiles.iter().enumerate() {
        let (cx, cy) = (i as u32 % cols * tw, i as u32 / cols * th + 30);
        image::imageops::overlay(&mut montage, t, cx as i64, cy as i64);
    }
    annotate(
        &mut montage,
        &[(
            8,
            4,
            "curriculum classification over time — green easy, yellow frontier, red hard, purple neither".into(),
            18,
        )],
    )?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| ExperimentError::file(dir, e))?;
    }
    montage.save(path).map_err(|e| ExperimentError::file(path, e))?;
    Ok(tiles.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_numbers_are_short() {
        let got: Vec<String> = [0.0, 0.25, 1500.0, 200_000.0, 3_000_000.0, -20_000.0].map(short_number).to_vec();
        assert_eq!(got, ["0", "0.25", "1.5k", "200k", "3M", "-20k"]);
    }

    #[test]
    fn moving_average_by_hand() {
        assert_eq!(moving_average(&[1.0, 2.0, 3.0, 4.0, 5.0], 3), vec![1.5, 2.0, 3.0, 4.0, 4.5]);
        assert_eq!(moving_average(&[7.0], 50), vec![7.0]);
    }
}
