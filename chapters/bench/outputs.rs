//! What `bench` writes besides its report: the rows as JSON (`bench.json`), a markdown table
//! (`bench.md`) and a plot of frame time by mode and size (`bench.svg`, with `plotters`).

use crate::{Mode, Row};
use anyhow::Result;
use common::instruments::output;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// `(ablation, equal)`: the ablation's table, and chapter 13's rays a frame at chapter 12's error.
pub fn write(
    dir: &Path,
    rows: &[Row],
    device: &str,
    driver: &str,
    (ablation, equal): (&str, &str),
) -> Result<()> {
    output::create_dir(dir)?;
    let json = serde_json::json!({ "device": device, "driver": driver, "rows": rows });
    let path = dir.join("bench.json");
    output::write_file(&path, serde_json::to_string_pretty(&json)?)?;
    let path = dir.join("bench.md");
    let text = format!(
        "Measured on {device} ({driver}).\n\n{}\nChapter 13's rows run at the rays a frame that reach \
         chapter 12's error at the row's spp, along chapter 13's orbit:\n\n{equal}\n\
         Chapter 12, one choice at a time:\n\n{ablation}",
        table(rows)
    );
    output::write_file(&path, text)?;
    let path = dir.join("bench.svg");
    output::draw_plot(&path, |path| plot(path, rows, device))?;
    eprintln!("wrote {}/bench.{{json,md,svg}}", dir.display());
    Ok(())
}

/// One markdown line per row; each scene's Grays/s also as a fraction of the ceiling scene's
/// at the same mode, size and rays (the best the traversal does). A row that gives no ray rate
/// (chapter 13's, whose pixels trace as many rays as their history asks) shows "–" in both.
pub fn table(rows: &[Row]) -> String {
    let mut table = String::from(
        "| mode | scene | size | spp | frame ms | p95 ms | raster ms | hand-over ms | AO ms | composite ms | Grays/s | of ceiling |\n\
         |---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        let ceiling = rows.iter().find(|c| {
            c.scene == "ceiling" && (c.mode, c.width, c.height, c.spp) == (r.mode, r.width, r.height, r.spp)
        });
        let fraction = ceiling
            .filter(|c| c.grays_per_s > 0.0 && r.grays_per_s > 0.0)
            .map_or("–".to_owned(), |c| format!("{:.0}%", 100.0 * r.grays_per_s / c.grays_per_s));
        let rate = if r.grays_per_s > 0.0 { three_figures(r.grays_per_s) } else { "–".to_owned() };
        let _ = writeln!(
            table,
            "| {} | {} | {}x{} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {} | {fraction} |",
            mode_name(r.mode),
            r.scene,
            r.width,
            r.height,
            r.spp,
            r.frame_ms,
            r.p95_ms,
            r.raster_ms,
            r.handoff_ms,
            r.ao_ms,
            r.composite_ms,
            rate
        );
    }
    table
}

/// A rate to three significant figures: a CPU's 0.000123 Grays/s and a GPU's 12.3 alike.
fn three_figures(value: f64) -> String {
    if value <= 0.0 || !value.is_finite() {
        return format!("{value}");
    }
    let decimals = (2 - value.log10().floor() as i32).max(0) as usize;
    format!("{value:.decimals$}")
}

fn mode_name(mode: Mode) -> &'static str {
    match mode {
        Mode::ZeroCopy => "zero-copy",
        Mode::HostSync => "host-sync",
        Mode::CpuRoundTrip => "cpu-round-trip",
        Mode::FastFrame => "fast-frame (12)",
        Mode::TemporalReuse => "temporal-reuse (13)",
        Mode::TemporalReuseCloser => "temporal-reuse (13), closer",
    }
}

/// Frame time against rays per pixel, both axes logarithmic: one panel per scene, one colour per
/// mode, thicker lines for larger sizes.
fn plot(path: &Path, rows: &[Row], device: &str) -> Result<()> {
    let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene).collect();
    scenes.dedup();
    let mut sizes: Vec<(u32, u32)> = rows.iter().map(|r| (r.width, r.height)).collect();
    sizes.sort();
    sizes.dedup();
    let positive = || rows.iter().filter(|r| r.frame_ms > 0.0);
    let (t0, t1) = positive().fold((f64::MAX, 0f64), |(a, b), r| (a.min(r.frame_ms), b.max(r.frame_ms)));
    let (s0, s1) = rows.iter().fold((u32::MAX, 0), |(a, b), r| (a.min(r.spp), b.max(r.spp)));
    anyhow::ensure!(t1 > 0.0, "nothing to plot");
    let root = SVGBackend::new(path, (360 * scenes.len().max(1) as u32, 420)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(&format!("Frame time by mode and size ({device})"), ("sans-serif", 18))?;
    let colours = [RED, BLUE, BLACK, GREEN, MAGENTA, CYAN];
    for (panel, scene) in root.split_evenly((1, scenes.len().max(1))).iter().zip(&scenes) {
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{scene} scene"), ("sans-serif", 15))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(52)
            .build_cartesian_2d(
                (s0 as f64 / 1.3..s1 as f64 * 1.3).log_scale(),
                (t0 / 1.5..t1 * 1.5).log_scale(),
            )?;
        chart
            .configure_mesh()
            .x_desc("rays per pixel")
            .y_desc("frame, ms")
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| three_figures(*v))
            .draw()?;
        for (m, mode) in Mode::ALL
            .iter()
            .chain([&Mode::FastFrame, &Mode::TemporalReuse, &Mode::TemporalReuseCloser])
            .enumerate()
        {
            let colour = colours[m];
            for (s, size) in sizes.iter().enumerate() {
                let points: Vec<(f64, f64)> = rows
                    .iter()
                    .filter(|r| r.scene == *scene && r.mode == *mode && (r.width, r.height) == *size)
                    .filter(|r| r.frame_ms > 0.0)
                    .map(|r| (r.spp as f64, r.frame_ms))
                    .collect();
                let series = chart
                    .draw_series(LineSeries::new(points.clone(), colour.stroke_width(1 + 2 * s as u32)))?;
                if s == 0 {
                    series
                        .label(mode_name(*mode))
                        .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour));
                }
                chart.draw_series(points.into_iter().map(|p| Circle::new(p, 3, colour.filled())))?;
            }
        }
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(mode: Mode, scene: &'static str, grays_per_s: f64) -> Row {
        let (width, height, spp) = (64, 48, 4);
        let (frame_ms, p95_ms, raster_ms, handoff_ms, ao_ms, composite_ms) = (1.0, 1.0, 0.2, 0.1, 0.5, 0.2);
        Row {
            mode,
            scene,
            width,
            height,
            spp,
            frame_ms,
            p95_ms,
            raster_ms,
            handoff_ms,
            ao_ms,
            composite_ms,
            grays_per_s,
        }
    }

    /// A row with a ray rate gives it and its share of the ceiling's; a row without one (chapter
    /// 13's) shows "–" in both, never a rate of 0.
    #[test]
    fn rows_without_a_ray_rate_say_so() {
        let rows = [
            row(Mode::FastFrame, "ceiling", 20.0),
            row(Mode::FastFrame, "default", 5.0),
            row(Mode::TemporalReuse, "ceiling", 0.0),
            row(Mode::TemporalReuse, "default", 0.0),
        ];
        let table = table(&rows);
        let lines: Vec<&str> = table.lines().skip(2).collect();
        assert!(lines[0].ends_with("| 20.0 | 100% |"), "{}", lines[0]);
        assert!(lines[1].ends_with("| 5.00 | 25% |"), "{}", lines[1]);
        for line in &lines[2..] {
            assert!(line.ends_with("| – | – |"), "{line}");
        }
    }
}
