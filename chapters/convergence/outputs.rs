//! What `convergence` writes besides its report: a CSV of every row, a markdown table, and a
//! log-log plot of error against GPU time (SVG, with the `plotters` crate).

use crate::CaseReport;
use anyhow::Result;
use common::instruments::output;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

pub fn write(dir: &Path, cases: &[CaseReport], device: &str) -> Result<()> {
    output::create_dir(dir)?;
    let mut csv = String::from(
        "scene,reference,spp,frames,rays_per_pixel,gpu_ms,rmse,max_abs,mean_error,standard_error\n",
    );
    // Which pixels were judged: finite planes stand in for infinite ones only a radius or more
    // from their edges; the default scene is judged at every covered pixel.
    let mut table = format!(
        "Measured on {device}. Exact cases: pixels at least R from every plane edge; \
         default scene: every covered pixel, against a long run of the same tracer.\n\n"
    );
    table.push_str("| scene | reference | rays/px/frame | frames | rays/px | GPU ms | RMSE | max abs | RMSE, independent rays |\n");
    table.push_str("|---|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for case in cases {
        for r in &case.rows {
            let rays = r.spp * r.frames;
            // The same five columns lead both: which case, and how many rays.
            let head = [case.scene, case.reference].map(String::from);
            let head = [&head[..], &[r.spp, r.frames, rays].map(|n| n.to_string())].concat();
            let (gpu_ms, rmse, max_abs) = (r.gpu_ms, r.rmse, r.max_abs);
            let (mean, standard) = (r.mean_error, r.standard_error);
            writeln!(csv, "{},{gpu_ms:.4},{rmse:.6},{max_abs:.6},{mean:.6},{standard:.6}", head.join(","))?;
            let independent = r.independent_rmse.map_or("".into(), |e| format!("{e:.4}"));
            let cells = format!("{gpu_ms:.3} | {rmse:.4} | {max_abs:.3} | {independent}");
            writeln!(table, "| {} | {cells} |", head.join(" | "))?;
        }
    }
    let path = dir.join("convergence.csv");
    output::write_file(&path, csv)?;
    let path = dir.join("convergence.md");
    output::write_file(&path, table)?;
    let path = dir.join("convergence.svg");
    output::draw_plot(&path, |path| plot(path, cases, device))?;
    eprintln!("wrote {}/convergence.{{csv,md,svg}}", dir.display());
    Ok(())
}

// ANCHOR: plot
/// RMSE against GPU time, both axes logarithmic: one line per case and rays per frame, each
/// point one number of frames (more frames: further right, lower).
fn plot(path: &Path, cases: &[CaseReport], device: &str) -> Result<()> {
    let rows = cases.iter().flat_map(|c| &c.rows).filter(|r| r.rmse > 0.0 && r.gpu_ms > 0.0);
    let caption = format!("AO error against GPU time ({device})");
    let axes = ("GPU time, ms (thicker: more rays per frame)", "RMSE of visibility");
    let labels: (output::TickLabel, output::TickLabel) = (&|v| format!("{v}"), &|v| format!("{v:.3}"));
    let points = rows.map(|r| (r.gpu_ms, r.rmse));
    output::log_log_plot(path, ((720, 480), &caption), axes, labels, points, |chart| {
        let colours = [RED, BLUE, GREEN, MAGENTA, CYAN, BLACK];
        for (i, case) in cases.iter().enumerate() {
            let colour = colours[i % colours.len()];
            let mut spps: Vec<u32> = case.rows.iter().map(|r| r.spp).collect();
            spps.dedup();
            for (j, &spp) in spps.iter().enumerate() {
                let points: Vec<(f64, f64)> = case
                    .rows
                    .iter()
                    .filter(|r| r.spp == spp && r.rmse > 0.0 && r.gpu_ms > 0.0)
                    .map(|r| (r.gpu_ms, r.rmse))
                    .collect();
                let series =
                    chart.draw_series(LineSeries::new(points.clone(), colour.stroke_width(1 + j as u32)))?;
                if j == 0 {
                    series
                        .label(case.scene)
                        .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour));
                }
                chart.draw_series(points.into_iter().map(|p| Circle::new(p, 3, colour.filled())))?;
            }
        }
        Ok(())
    })
}
// ANCHOR_END: plot
