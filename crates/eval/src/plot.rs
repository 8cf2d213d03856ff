//! PNG plots for the reports: line charts (several panels side by side) and heat maps over the
//! yaw x pitch grid. Drawn in memory with plotters' bitmap backend and encoded to PNG bytes here;
//! the caller writes them. Text uses an embedded subset of DejaVu Sans
//! (`assets/fonts/`, Bitstream Vera licence), so no system font library is needed.

use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

use super::paper::HeatMap;

/// A plot that could not be drawn or encoded.
#[derive(Debug, thiserror::Error)]
#[error("plot: {0}")]
pub struct PlotError(String);

fn err(e: impl std::fmt::Display) -> PlotError {
    PlotError(e.to_string())
}

static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans-subset.ttf");

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is a constant of the build; a failure here is caught by the plot tests.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Distinct colours (Tableau 10), one per series in order.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// One line of a chart.
#[derive(Debug, Clone)]
pub struct Series {
    /// The legend's name.
    pub name: String,
    /// The points `(x, y)`, in the panel's units.
    pub points: Vec<(f64, f64)>,
}

/// One chart panel.
#[derive(Debug, Clone)]
pub struct Panel {
    /// The panel's title.
    pub title: String,
    /// The x axis' label.
    pub x_label: String,
    /// The y axis' label.
    pub y_label: String,
    /// The lines.
    pub series: Vec<Series>,
}

/// Encodes an RGB buffer as PNG.
fn encode_png(rgb: &[u8], w: u32, h: u32) -> Result<Vec<u8>, PlotError> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(err)?;
        writer.write_image_data(rgb).map_err(err)?;
        writer.finish().map_err(err)?;
    }
    Ok(out)
}

/// Draws into an in-memory bitmap and returns the PNG.
fn render(
    w: u32,
    h: u32,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), PlotError>,
) -> Result<Vec<u8>, PlotError> {
    register_font();
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        draw(&root)?;
        root.present().map_err(err)?;
    }
    encode_png(&buf, w, h)
}

/// Tick labels without needless decimals: `10`, `2.5`.
fn tick(v: &f64) -> String {
    if (v - v.round()).abs() < 1e-9 {
        format!("{v:.0}")
    } else {
        let s = format!("{v:.2}");
        s.trim_end_matches('0').to_string()
    }
}

fn nice_max(v: f64) -> f64 {
    if !(v.is_finite() && v > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(v.log10().floor());
    for m in [1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0] {
        if m * p >= v {
            return m * p;
        }
    }
    10.0 * p
}

/// Marker outlines in pixels around the origin, one per series in turn (octagon, triangle,
/// square, diamond, inverted triangle): series that coincide stay distinguishable.
fn marker_polygon(i: usize) -> Vec<(i32, i32)> {
    match i % 5 {
        0 => vec![
            (-2, -5),
            (2, -5),
            (5, -2),
            (5, 2),
            (2, 5),
            (-2, 5),
            (-5, 2),
            (-5, -2),
        ],
        1 => vec![(0, -5), (-5, 4), (5, 4)],
        2 => vec![(-4, -4), (4, -4), (4, 4), (-4, 4)],
        3 => vec![(0, -6), (5, 0), (0, 6), (-5, 0)],
        _ => vec![(0, 5), (-5, -4), (5, -4)],
    }
}

/// Width of one legend entry, pixels.
const LEGEND_ENTRY_WIDTH: u32 = 230;

/// One legend for the whole figure, under the panels: a line, the marker and the name per
/// series, `per_row` entries a row.
fn draw_legend(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    names: &[&str],
    per_row: usize,
) -> Result<(), PlotError> {
    for (i, name) in names.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let x = 40 + (i % per_row) as i32 * LEGEND_ENTRY_WIDTH as i32;
        let y = 12 + (i / per_row) as i32 * 24;
        area.draw(&PathElement::new(
            vec![(x, y), (x + 24, y)],
            color.stroke_width(2),
        ))
        .map_err(err)?;
        area.draw(&Polygon::new(
            marker_polygon(i)
                .into_iter()
                .map(|(a, b)| (a + x + 12, b + y))
                .collect::<Vec<_>>(),
            color.filled(),
        ))
        .map_err(err)?;
        area.draw(&Text::new(
            name.to_string(),
            (x + 32, y - 8),
            ("sans-serif", 15).into_font(),
        ))
        .map_err(err)?;
    }
    Ok(())
}

/// Line charts with markers, `panels` side by side under a common title and over one legend;
/// each series keeps its colour and marker across panels (by name), and is shifted sideways
/// by 0.5% of the x range per series so that coinciding series stay visible.
pub fn line_chart_png(title: &str, panels: &[Panel]) -> Result<Vec<u8>, PlotError> {
    let (pw, ph) = (560u32, 440u32);
    let mut names: Vec<&str> = Vec::new();
    for p in panels {
        for s in &p.series {
            if !names.contains(&s.name.as_str()) {
                names.push(&s.name);
            }
        }
    }
    let w = pw * panels.len().max(1) as u32;
    let per_row = ((w - 40) / LEGEND_ENTRY_WIDTH).max(1) as usize;
    let legend_h = 16 + 24 * names.len().div_ceil(per_row) as u32;
    let h = ph + 40 + legend_h;
    render(w, h, |root| {
        let body = root
            .titled(title, ("sans-serif", 24).into_font())
            .map_err(err)?;
        let (body, legend) = body.split_vertically(ph);
        draw_legend(&legend, &names, per_row)?;
        let cells = body.split_evenly((1, panels.len().max(1)));
        for (panel, area) in panels.iter().zip(cells.iter()) {
            let pts = panel.series.iter().flat_map(|s| s.points.iter());
            let (mut x0, mut x1, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
            for &(x, y) in pts {
                if x.is_finite() && y.is_finite() {
                    x0 = x0.min(x);
                    x1 = x1.max(x);
                    y1 = y1.max(y);
                }
            }
            if !x0.is_finite() {
                (x0, x1) = (0.0, 1.0);
            }
            let pad = ((x1 - x0) * 0.04).max(1e-6);
            let mut chart = ChartBuilder::on(area)
                .caption(&panel.title, ("sans-serif", 18).into_font())
                .margin(12)
                .x_label_area_size(44)
                .y_label_area_size(56)
                .build_cartesian_2d((x0 - pad)..(x1 + pad), 0.0..nice_max(y1 * 1.05))
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc(&panel.x_label)
                .y_desc(&panel.y_label)
                .axis_desc_style(("sans-serif", 15))
                .label_style(("sans-serif", 13))
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .light_line_style(RGBColor(240, 240, 240))
                .draw()
                .map_err(err)?;
            for s in &panel.series {
                let i = names.iter().position(|n| *n == s.name).unwrap_or(0);
                let color = PALETTE[i % PALETTE.len()];
                // A small sideways dodge per series, so that equal values stay visible.
                let dodge = (i as f64 - (names.len() as f64 - 1.0) / 2.0) * (x1 - x0) * 0.005;
                let line: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .filter(|(x, y)| x.is_finite() && y.is_finite())
                    .map(|(x, y)| (x + dodge, y))
                    .collect();
                chart
                    .draw_series(LineSeries::new(line.clone(), color.stroke_width(2)))
                    .map_err(err)?;
                let poly = marker_polygon(i);
                chart
                    .draw_series(
                        line.iter().map(|&p| {
                            EmptyElement::at(p) + Polygon::new(poly.clone(), color.filled())
                        }),
                    )
                    .map_err(err)?;
            }
        }
        Ok(())
    })
}

/// Viridis, sampled at nine points and interpolated linearly; `t` in [0, 1].
pub fn viridis(t: f64) -> RGBColor {
    const C: [(u8, u8, u8); 9] = [
        (68, 1, 84),
        (71, 44, 122),
        (59, 81, 139),
        (44, 113, 142),
        (33, 144, 141),
        (39, 173, 129),
        (92, 200, 99),
        (170, 220, 50),
        (253, 231, 37),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (C.len() - 1) as f64;
    let i = (x.floor() as usize).min(C.len() - 2);
    let f = x - i as f64;
    let mix = |a: u8, b: u8| (a as f64 + f * (b as f64 - a as f64)).round() as u8;
    RGBColor(
        mix(C[i].0, C[i + 1].0),
        mix(C[i].1, C[i + 1].1),
        mix(C[i].2, C[i + 1].2),
    )
}

/// The `q` quantile (nearest rank) of finite values; 0 when there are none.
fn percentile(values: impl Iterator<Item = f64>, q: f64) -> f64 {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)]
}

/// Heat maps of error over the yaw x pitch grid, one panel per map (three per row), each
/// with its own colour scale (0 to its 95th percentile, rounded up; larger cells take the top
/// colour) and colour bar; cells without an estimate are grey.
pub fn heat_maps_png(title: &str, maps: &[HeatMap], unit: &str) -> Result<Vec<u8>, PlotError> {
    let cols = maps.len().clamp(1, 3);
    let rows = maps.len().div_ceil(cols).max(1);
    let (pw, ph) = (480u32, 420u32);
    let (w, h) = (pw * cols as u32, ph * rows as u32 + 40);
    render(w, h, |root| {
        let body = root
            .titled(title, ("sans-serif", 24).into_font())
            .map_err(err)?;
        let cells = body.split_evenly((rows, cols));
        for (map, area) in maps.iter().zip(cells.iter()) {
            let (main, bar) = area.split_horizontally(pw - 90);
            let step = |v: &[f64]| {
                if v.len() > 1 {
                    (v[1] - v[0]).abs()
                } else {
                    1.0
                }
            };
            let (sy, sp) = (step(&map.yaw), step(&map.pitch));
            let (ymin, ymax) = (
                map.yaw.first().copied().unwrap_or(0.0) - sy / 2.0,
                map.yaw.last().copied().unwrap_or(0.0) + sy / 2.0,
            );
            let (pmin, pmax) = (
                map.pitch.first().copied().unwrap_or(0.0) - sp / 2.0,
                map.pitch.last().copied().unwrap_or(0.0) + sp / 2.0,
            );
            let vmax = nice_max(percentile(map.values.iter().flatten().copied(), 0.95));
            let mut chart = ChartBuilder::on(&main)
                .caption(&map.label, ("sans-serif", 17).into_font())
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(52)
                .build_cartesian_2d(ymin..ymax, pmin..pmax)
                .map_err(err)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("yaw (°)")
                .y_desc("pitch (°)")
                .axis_desc_style(("sans-serif", 14))
                .label_style(("sans-serif", 12))
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .draw()
                .map_err(err)?;
            let ny = map.yaw.len();
            chart
                .draw_series(map.values.iter().enumerate().map(|(i, v)| {
                    let (y, p) = (map.yaw[i % ny], map.pitch[i / ny]);
                    let color = match v {
                        Some(v) => viridis(v / vmax).filled(),
                        None => RGBColor(200, 200, 200).filled(),
                    };
                    Rectangle::new(
                        [(y - sy / 2.0, p - sp / 2.0), (y + sy / 2.0, p + sp / 2.0)],
                        color,
                    )
                }))
                .map_err(err)?;
            let mut cb = ChartBuilder::on(&bar)
                .margin_top(36)
                .margin_bottom(48)
                .margin_right(8)
                .y_label_area_size(44)
                .build_cartesian_2d(0.0..1.0, 0.0..vmax)
                .map_err(err)?;
            cb.configure_mesh()
                .disable_mesh()
                .disable_x_axis()
                .y_desc(unit)
                .axis_desc_style(("sans-serif", 12))
                .label_style(("sans-serif", 12))
                .y_label_formatter(&tick)
                .draw()
                .map_err(err)?;
            let n = 64;
            cb.draw_series((0..n).map(|k| {
                let a = vmax * k as f64 / n as f64;
                let b = vmax * (k + 1) as f64 / n as f64;
                Rectangle::new(
                    [(0.0, a), (1.0, b)],
                    viridis((k as f64 + 0.5) / n as f64).filled(),
                )
            }))
            .map_err(err)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

    fn size(png: &[u8]) -> (u32, u32) {
        let be = |i: usize| u32::from_be_bytes([png[i], png[i + 1], png[i + 2], png[i + 3]]);
        (be(16), be(20))
    }

    #[test]
    fn a_line_chart_is_a_png_of_the_expected_size() {
        let panel = |t: &str| Panel {
            title: t.into(),
            x_label: "noise (% IOD)".into(),
            y_label: "MAE (°)".into(),
            series: vec![
                Series {
                    name: "fit, 68 points".into(),
                    points: vec![(0.0, 0.5), (1.0, 1.0), (5.0, 3.0)],
                },
                Series {
                    name: "geometry, 5 points".into(),
                    points: vec![(0.0, 2.0), (1.0, f64::NAN), (5.0, 9.0)],
                },
            ],
        };
        let png = line_chart_png("Robustness", &[panel("a"), panel("b")]).unwrap();
        assert_eq!(png[..8], SIGNATURE);
        // Two panels, the title and one legend row.
        assert_eq!(size(&png), (2 * 560, 440 + 40 + 16 + 24));
        // Not a blank page: a white 1120x480 RGB image compresses to far less.
        assert!(png.len() > 10_000, "{} bytes", png.len());
    }

    #[test]
    fn a_heat_map_is_a_png_with_one_panel_per_map() {
        let map = |l: &str| HeatMap {
            label: l.into(),
            yaw: vec![-2.0, 0.0, 2.0],
            pitch: vec![-2.0, 0.0],
            values: vec![Some(0.0), Some(1.0), None, Some(2.0), Some(3.0), Some(4.0)],
        };
        let png = heat_maps_png(
            "Error",
            &[map("a"), map("b"), map("c"), map("d")],
            "MAE (°)",
        )
        .unwrap();
        assert_eq!(png[..8], SIGNATURE);
        assert_eq!(size(&png), (3 * 480, 2 * 420 + 40));
    }

    #[test]
    fn viridis_runs_from_purple_to_yellow() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(f64::NAN), viridis(0.0));
    }
}

/// One panel of landmark sets drawn over each other in image coordinates (x right, y down):
/// each set as its points, its first `outline` points joined (the jaw of ibug68).
#[derive(Debug, Clone)]
pub struct LandmarkPanel {
    /// The panel's title.
    pub title: String,
    /// How many of each set's first points are joined as an outline.
    pub outline: usize,
    /// (name, points) per set.
    pub sets: Vec<(String, Vec<[f64; 2]>)>,
    /// The sets (positions in `sets`) whose points are labelled with their index.
    pub numbered: Vec<usize>,
}

/// Landmark panels side by side, equal scale on both axes, image y downwards.
pub fn landmarks_png(title: &str, panels: &[LandmarkPanel]) -> Result<Vec<u8>, PlotError> {
    let side = 380u32;
    let mut names: Vec<&str> = Vec::new();
    for p in panels {
        for (n, _) in &p.sets {
            if !names.contains(&n.as_str()) {
                names.push(n);
            }
        }
    }
    let w = side * panels.len().max(1) as u32;
    let per_row = ((w - 40) / LEGEND_ENTRY_WIDTH).max(1) as usize;
    let legend_h = 16 + 24 * names.len().div_ceil(per_row) as u32;
    render(w, side + 40 + legend_h, |root| {
        let body = root
            .titled(title, ("sans-serif", 22).into_font())
            .map_err(err)?;
        let (body, legend) = body.split_vertically(side);
        draw_legend(&legend, &names, per_row)?;
        let cells = body.split_evenly((1, panels.len().max(1)));
        for (panel, area) in panels.iter().zip(cells.iter()) {
            let all = panel.sets.iter().flat_map(|(_, p)| p.iter());
            let (mut x0, mut x1, mut y0, mut y1) = (
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            );
            for p in all {
                x0 = x0.min(p[0]);
                x1 = x1.max(p[0]);
                y0 = y0.min(p[1]);
                y1 = y1.max(p[1]);
            }
            if !x0.is_finite() || !y0.is_finite() {
                continue;
            }
            // A square window around the points, so both axes share one scale.
            let half = 0.55 * (x1 - x0).max(y1 - y0).max(1.0);
            let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
            let mut chart = ChartBuilder::on(area)
                .caption(&panel.title, ("sans-serif", 15).into_font())
                .margin(10)
                .x_label_area_size(30)
                .y_label_area_size(40)
                .build_cartesian_2d((cx - half)..(cx + half), (cy + half)..(cy - half))
                .map_err(err)?;
            chart
                .configure_mesh()
                .label_style(("sans-serif", 12))
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .light_line_style(RGBColor(240, 240, 240))
                .draw()
                .map_err(err)?;
            for (k, (name, pts)) in panel.sets.iter().enumerate() {
                let i = names.iter().position(|n| n == name).unwrap_or(0);
                let color = PALETTE[i % PALETTE.len()];
                let line: Vec<(f64, f64)> = pts
                    .iter()
                    .take(panel.outline)
                    .map(|p| (p[0], p[1]))
                    .collect();
                chart
                    .draw_series(LineSeries::new(line, color.stroke_width(2)))
                    .map_err(err)?;
                let poly = marker_polygon(i);
                chart
                    .draw_series(pts.iter().map(|p| {
                        EmptyElement::at((p[0], p[1])) + Polygon::new(poly.clone(), color.filled())
                    }))
                    .map_err(err)?;
                if panel.numbered.contains(&k) {
                    let font = ("sans-serif", 14).into_font().color(&color);
                    chart
                        .draw_series(pts.iter().enumerate().map(|(j, p)| {
                            EmptyElement::at((p[0], p[1]))
                                + Text::new(j.to_string(), (5, -16), font.clone())
                        }))
                        .map_err(err)?;
                }
            }
        }
        Ok(())
    })
}
