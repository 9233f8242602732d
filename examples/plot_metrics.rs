//! Line plot of one `metrics.csv` column against time, for one or more runs, drawn with
//! [`treacle::plot`] (the crate's `plot` feature, on by default).
//!
//! ```text
//! cargo run --release --example plot_metrics -- OUT.png COLUMN LABEL=RUN/metrics.csv [LABEL=...]
//! cargo run --release --example plot_metrics -- melt.png melted_fraction \
//!     bunny_1=out/bunny_melting_1/metrics.csv bunny_2=out/bunny_melting_2/metrics.csv
//! ```
//! The x axis is the `time` column [s]; rows with a non-finite value are skipped. A `LABEL=`
//! prefix may be left out (the file name is used); the label ends at the last `=`. Prints the plotted values as a table.

#[cfg(feature = "plot")]
fn main() {
    if let Err(e) = run() {
        eprintln!("plot_metrics: {e}");
        std::process::exit(1);
    }
}

#[cfg(not(feature = "plot"))]
fn main() {
    eprintln!("plot_metrics needs the `plot` feature (on by default)");
    std::process::exit(1);
}

/// One run's series: label and (t, value) points.
#[cfg(feature = "plot")]
type Series = (String, Vec<(f64, f64)>);

#[cfg(feature = "plot")]
fn read_series(spec: &str, column: &str) -> Result<Series, String> {
    let (label, path) = match spec.rsplit_once('=') {
        Some((l, p)) => (l.to_string(), p.to_string()),
        None => (spec.to_string(), spec.to_string()),
    };
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{path}: {e}"))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or(format!("{path}: empty"))?
        .split(',')
        .collect();
    let col = |name: &str| {
        header.iter().position(|h| h.trim() == name).ok_or(format!(
            "{path}: no column `{name}` (columns: {})",
            header.join(", ")
        ))
    };
    let (it, ic) = (col("time")?, col(column)?);
    let mut points = Vec::new();
    for (n, line) in lines.enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        let parse = |i: usize| -> Result<f64, String> {
            cells
                .get(i)
                .ok_or(format!("{path}:{}: too few columns", n + 2))?
                .trim()
                .parse::<f64>()
                .map_err(|e| format!("{path}:{}: {e}", n + 2))
        };
        let (t, v) = (parse(it)?, parse(ic)?);
        if t.is_finite() && v.is_finite() {
            points.push((t, v));
        }
    }
    Ok((label, points))
}

#[cfg(feature = "plot")]
fn run() -> Result<(), String> {
    use plotters::prelude::*;
    use treacle::plot::{Canvas, font_size_for};

    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        return Err(
            "usage: plot_metrics OUT.png COLUMN LABEL=metrics.csv [LABEL=metrics.csv ...]".into(),
        );
    }
    let (out, column) = (&args[0], &args[1]);
    let series = args[2..]
        .iter()
        .map(|s| read_series(s, column))
        .collect::<Result<Vec<_>, _>>()?;
    let all = series.iter().flat_map(|(_, p)| p.iter());
    let (mut t1, mut vmin, mut vmax) = (0.0f64, f64::INFINITY, f64::NEG_INFINITY);
    for &(t, v) in all {
        t1 = t1.max(t);
        vmin = vmin.min(v);
        vmax = vmax.max(v);
    }
    if !vmin.is_finite() {
        return Err("no data points".into());
    }
    let (vmin, vmax) = if column == "melted_fraction" {
        (0.0, 1.0)
    } else if vmax > vmin {
        (vmin, vmax)
    } else {
        (vmin - 1.0, vmax + 1.0)
    };
    let t1 = if t1 > 0.0 { t1 } else { 1.0 };

    let (w, h) = (800u32, 500u32);
    let mut canvas = Canvas::new(w, h).map_err(|e| e.to_string())?;
    {
        let area = canvas.area().map_err(|e| e.to_string())?;
        area.fill(&WHITE).map_err(|e| e.to_string())?;
        let fs = font_size_for(h);
        let mut chart = ChartBuilder::on(&area)
            .caption(format!("{column} against time"), ("sans-serif", fs * 1.2))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..t1, vmin..vmax)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("t [s]")
            .y_desc(column.as_str())
            .label_style(("sans-serif", fs))
            .draw()
            .map_err(|e| e.to_string())?;
        let colours = [BLUE, RED, GREEN, MAGENTA, CYAN, BLACK];
        for (i, (label, points)) in series.iter().enumerate() {
            let c = colours[i % colours.len()];
            chart
                .draw_series(std::iter::once(PathElement::new(
                    points.clone(),
                    c.stroke_width(2),
                )))
                .map_err(|e| e.to_string())?
                .label(label.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                });
            chart
                .draw_series(points.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map_err(|e| e.to_string())?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", fs))
            .draw()
            .map_err(|e| e.to_string())?;
        area.present().map_err(|e| e.to_string())?;
    }
    canvas
        .write_png(std::path::Path::new(out))
        .map_err(|e| e.to_string())?;
    for (label, points) in &series {
        println!("{label}: t [s] -> {column}");
        for (t, v) in points {
            println!("  {t:.4}  {v:.4}");
        }
    }
    println!("wrote {out}");
    Ok(())
}
