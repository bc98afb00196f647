//! The report's figures, drawn with `plotters` into PNGs: a title, axes captioned with their units, tick
//! labels, a legend naming every strategy (colour by strategy, marker shape by family), and log axes
//! where the values span a decade or more. Text comes from a font embedded in the binary
//! (`fonts/Go-Regular.ttf`, BSD licence beside it), so the figures need no system font.
//! The report draws two figures per scene and one overview, each rasterised in memory on the CPU and
//! written as PNG: a small cost beside the scene runs they show.

use super::harness::{FrameRecord, Strategy};
use super::output::Row;
use super::scale::Scale;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use std::error::Error;
use std::path::Path;
use std::sync::OnceLock;

/// Pixel size of `SCENE.png`, error against time per frame.
pub const ERROR_VS_TIME: (u32, u32) = (1100, 700);
/// Pixel size of `SCENE-frames.png`, time and error frame by frame.
pub const PER_FRAME: (u32, u32) = (1100, 900);
/// Pixel size of `overview.png`, every scene side by side.
pub const OVERVIEW: (u32, u32) = (1200, 900);

/// The family name the embedded font is registered under.
const FONT: &str = "sans-serif";
/// Width of the legend column right of the plots.
const LEGEND_WIDTH: u32 = 260;

type Drawn = Result<(), Box<dyn Error>>;
type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Colours of the strategies, in [`Strategy::all`] order: none grey, so none is mistaken for text.
const COLOURS: [RGBColor; 11] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
    RGBColor(0, 0, 128),
    RGBColor(128, 0, 0),
];

/// How a strategy is drawn: its colour, and a marker shape shared by its family.
#[derive(Clone, Copy)]
pub struct Look {
    pub colour: RGBColor,
    shape: Shape,
}

/// Marker shapes: full rebuilds, refits, Lauterbach's heuristic, the adaptive policy.
#[derive(Clone, Copy)]
enum Shape {
    Circle,
    Square,
    Triangle,
    Diamond,
}

/// The looks of `strategies`, in order.
pub fn looks(strategies: &[Strategy]) -> Vec<Look> {
    strategies
        .iter()
        .enumerate()
        .map(|(i, s)| Look {
            colour: COLOURS[i % COLOURS.len()],
            shape: match s {
                Strategy::Rebuild(_) => Shape::Circle,
                Strategy::Refit | Strategy::RefitPartial | Strategy::RefitEvery(_) => Shape::Square,
                Strategy::Lauterbach(_) => Shape::Triangle,
                Strategy::Adaptive { .. } => Shape::Diamond,
                Strategy::Structure(_) => Shape::Square,
                Strategy::Options(o) if !o.is_fixed() => Shape::Diamond,
                Strategy::Options(_) => Shape::Triangle,
            },
        })
        .collect()
}

/// A filled marker of radius about `r` pixels at `at`.
fn marker<C, DB: DrawingBackend>(
    at: C,
    look: Look,
    r: f64,
) -> <EmptyElement<C, DB> as std::ops::Add<Polygon<(i32, i32)>>>::Output {
    let corners: Vec<(f64, f64)> = match look.shape {
        Shape::Circle => (0..16)
            .map(|i| f64::from(i) * std::f64::consts::TAU / 16.0)
            .map(|a| (a.cos(), a.sin()))
            .collect(),
        Shape::Square => vec![(-0.85, -0.85), (0.85, -0.85), (0.85, 0.85), (-0.85, 0.85)],
        Shape::Triangle => vec![(0.0, -1.15), (1.05, 0.75), (-1.05, 0.75)],
        Shape::Diamond => vec![(0.0, -1.35), (1.15, 0.0), (0.0, 1.35), (-1.15, 0.0)],
    };
    let pixels = corners
        .iter()
        .map(|(x, y)| ((x * r).round() as i32, (y * r).round() as i32));
    EmptyElement::at(at) + Polygon::new(pixels.collect::<Vec<_>>(), look.colour.filled())
}

/// Makes the embedded font the one plotters draws text with (once per process).
fn font_ready() -> Result<(), Box<dyn Error>> {
    static READY: OnceLock<bool> = OnceLock::new();
    let ok = *READY.get_or_init(|| {
        register_font(
            FONT,
            FontStyle::Normal,
            include_bytes!("fonts/Go-Regular.ttf"),
        )
        .is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err("the embedded font fonts/Go-Regular.ttf cannot be read".into())
    }
}

fn text(size: u32) -> TextStyle<'static> {
    (FONT, size).into_font().color(&BLACK)
}

/// Draws a `size` figure with `draw` and saves it as a PNG at `path`.
fn save(path: &Path, size: (u32, u32), draw: impl FnOnce(&Area) -> Drawn) -> std::io::Result<()> {
    let mut pixels = vec![0u8; size.0 as usize * size.1 as usize * 3];
    let drawn = font_ready().and_then(|()| {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
        Ok(())
    });
    drawn.map_err(|e| std::io::Error::other(format!("drawing {}: {e}", path.display())))?;
    let img =
        image::RgbImage::from_raw(size.0, size.1, pixels).expect("buffer of the figure's size");
    img.save(path).map_err(std::io::Error::other)
}

/// Splits off a titled column on the right holding the legend: one line per strategy with its marker
/// (and a line sample when `lines`), then `notes`. Returns the area left for the plots.
fn with_legend<'a>(
    root: &Area<'a>,
    title: &str,
    names: &[String],
    looks: &[Look],
    lines: bool,
    notes: &[&str],
) -> Result<Area<'a>, Box<dyn Error>> {
    let root = root.margin(10, 0, 0, 0).titled(title, text(26))?;
    let width = root.dim_in_pixel().0;
    let (plots, legend) = root.split_horizontally(width - LEGEND_WIDTH);
    legend.draw(&Text::new("strategy", (14, 20), text(19)))?;
    let mut y = 52;
    for (name, &look) in names.iter().zip(looks) {
        if lines {
            legend.draw(&PathElement::new(
                vec![(8, y), (44, y)],
                look.colour.stroke_width(2),
            ))?;
        }
        legend.draw(&marker((26, y), look, 6.0))?;
        legend.draw(&Text::new(name.as_str(), (54, y - 9), text(17)))?;
        y += 27;
    }
    y += 10;
    for note in notes {
        legend.draw(&Text::new(*note, (14, y), text(15)))?;
        y += 21;
    }
    Ok(plots)
}

/// Caption of an axis, marked "(log scale)" when it is.
fn caption(what: &str, scale: &Scale) -> String {
    if scale.is_log() {
        format!("{what}, log scale")
    } else {
        what.to_string()
    }
}

/// `SCENE.png`: per strategy, mean SAH ratio (up) against mean update + query milliseconds per frame
/// (right), with the per-frame minimum–maximum of each as bars.
pub fn error_vs_time(
    path: &Path,
    scene: &str,
    rows: &[Row],
    looks: &[Look],
    frames: u32,
) -> std::io::Result<()> {
    save(path, ERROR_VS_TIME, |root| {
        let names: Vec<String> = rows.iter().map(|r| r.strategy.clone()).collect();
        let notes = [
            &format!("marker: mean of {frames} frames")[..],
            "bars: fastest to slowest frame,",
            "    lowest to highest error",
        ];
        let title = format!("{scene}: tree error against time per frame");
        let plots = with_legend(root, &title, &names, looks, false, &notes)?;
        let x = Scale::fit(
            rows.iter().flat_map(|r| [r.spread[0].0, r.spread[1].0]),
            true,
        );
        let y = Scale::fit(
            rows.iter().flat_map(|r| [r.spread[0].1, r.spread[1].1]),
            true,
        );
        let x_desc = caption("update + query time per frame (ms)", &x);
        let y_desc = caption("SAH cost / fresh SAH build's (1 = best)", &y);
        let mut chart = ChartBuilder::on(&plots)
            .margin(16)
            .x_label_area_size(56)
            .y_label_area_size(84)
            .build_cartesian_2d(x, y)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .axis_desc_style(text(19))
            .label_style(text(16))
            .draw()?;
        for (r, &look) in rows.iter().zip(looks) {
            let [(t0, e0), (t1, e1)] = r.spread;
            let style = look.colour.stroke_width(2);
            chart.draw_series([ErrorBar::new_horizontal(
                r.sah_mean, t0, r.total_ms, t1, style, 10,
            )])?;
            chart.draw_series([ErrorBar::new_vertical(
                r.total_ms, e0, r.sah_mean, e1, style, 10,
            )])?;
            chart.draw_series([marker((r.total_ms, r.sah_mean), look, 8.0)])?;
        }
        Ok(())
    })
}

/// `SCENE-frames.png`: frame by frame, update + query milliseconds (top) and SAH ratio (bottom), one
/// line per strategy.
pub fn per_frame(
    path: &Path,
    scene: &str,
    names: &[String],
    looks: &[Look],
    per_strategy: &[Vec<FrameRecord>],
) -> std::io::Result<()> {
    save(path, PER_FRAME, |root| {
        let title = format!("{scene}: time and tree error, frame by frame");
        let plots = with_legend(root, &title, names, looks, true, &[])?;
        let (top, bottom) = plots.split_vertically(PER_FRAME.1 / 2 - 20);
        let ms = |r: &FrameRecord| 1e3 * (r.update_s + r.query_s);
        let sah = |r: &FrameRecord| r.sah_ratio;
        let last = per_strategy
            .iter()
            .flatten()
            .map(|r| r.frame)
            .max()
            .unwrap_or(0);
        for (area, value, what) in [
            (
                &top,
                &ms as &dyn Fn(&FrameRecord) -> f64,
                "update + query time (ms)",
            ),
            (&bottom, &sah, "SAH cost / fresh SAH build's"),
        ] {
            let y = Scale::fit(per_strategy.iter().flatten().map(value), true);
            let y_desc = caption(what, &y);
            let mut chart = ChartBuilder::on(area)
                .margin(14)
                .x_label_area_size(52)
                .y_label_area_size(84)
                .build_cartesian_2d(Scale::linear(0.0, f64::from(last.max(1))), y)?;
            chart
                .configure_mesh()
                .x_desc("frame")
                .y_desc(y_desc)
                .axis_desc_style(text(19))
                .label_style(text(16))
                .draw()?;
            for (recs, &look) in per_strategy.iter().zip(looks) {
                let points = recs.iter().map(|r| (f64::from(r.frame), value(r)));
                chart.draw_series(LineSeries::new(points, look.colour.stroke_width(2)))?;
            }
        }
        Ok(())
    })
}

/// `overview.png`: every scene side by side, per strategy the mean time per frame over the scene's
/// fastest fixed strategy's (top) and the mean SAH ratio (bottom).
pub fn overview(
    path: &Path,
    rows: &[Row],
    names: &[String],
    looks: &[Look],
) -> std::io::Result<()> {
    save(path, OVERVIEW, |root| {
        let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene).collect();
        scenes.dedup();
        let fastest = |scene: &str| {
            let fixed = rows.iter().filter(|r| r.scene == scene && r.fixed);
            fixed.map(|r| r.total_ms).fold(f64::INFINITY, f64::min)
        };
        let relative = |r: &Row| r.total_ms / fastest(r.scene);
        let sah = |r: &Row| r.sah_mean;
        let plots = with_legend(
            root,
            "All scenes: time and tree error per strategy",
            names,
            looks,
            false,
            &[
                "marker: mean over all frames",
                "black line at 1: the fastest fixed",
                "    strategy (top), a fresh SAH",
                "    build (bottom)",
            ],
        )?;
        let (top, bottom) = plots.split_vertically(OVERVIEW.1 / 2 - 20);
        let n = scenes.len().max(1) as f64;
        let label = |x: &f64| {
            let i = x.round();
            let name = scenes.get(i as usize).filter(|_| (x - i).abs() < 1e-6);
            name.map_or(String::new(), |s| s.to_string())
        };
        for (area, value, what) in [
            (
                &top,
                &relative as &dyn Fn(&Row) -> f64,
                "time per frame / fastest fixed strategy's",
            ),
            (&bottom, &sah, "SAH cost / fresh SAH build's"),
        ] {
            let y = Scale::fit(rows.iter().map(value).chain([1.0]), true);
            let y_desc = caption(what, &y);
            let (lo, hi) = (y.range().start, y.range().end);
            let x = Scale::slots(scenes.len());
            let mut chart = ChartBuilder::on(area)
                .margin(14)
                .x_label_area_size(40)
                .y_label_area_size(84)
                .build_cartesian_2d(x, y)?;
            chart
                .configure_mesh()
                .y_desc(y_desc)
                .axis_desc_style(text(19))
                .label_style(text(16))
                .x_label_formatter(&label)
                .disable_x_mesh()
                .draw()?;
            chart.draw_series([PathElement::new(
                vec![(-0.5, 1.0), (n - 0.5, 1.0)],
                BLACK.stroke_width(1),
            )])?;
            for (s, scene) in scenes.iter().enumerate() {
                let of_scene = rows.iter().filter(|r| r.scene == *scene);
                let count = of_scene.clone().count().max(1) as f64;
                for (k, (r, &look)) in of_scene.zip(looks).enumerate() {
                    // Strategies side by side within the scene's slot, in legend order.
                    let at = s as f64 + 0.7 * ((k as f64 + 0.5) / count - 0.5);
                    chart.draw_series([marker((at, value(r)), look, 7.0)])?;
                }
                if s > 0 {
                    let edge = s as f64 - 0.5;
                    chart.draw_series([PathElement::new(
                        vec![(edge, lo), (edge, hi)],
                        RGBColor(200, 200, 200).stroke_width(1),
                    )])?;
                }
            }
        }
        Ok(())
    })
}
