//! Tracks a coiling rope in a run directory (`treacle run SCENE --out DIR`): per frame, the
//! centroid of the particles in a horizontal band about a vertical axis
//! (`treacle::report::coiling`), then the coil's mean radius, angular frequency and turns over
//! a time window, and the fold period of a sheet folding along x.
//!
//! ```sh
//! cargo run --release --example coil_track -- DIR AXIS_X AXIS_Z Y0 Y1 [T0 T1]
//! cargo run --release --example coil_track -- target/gallery/coiling_1 0.03 0.03 0.012 0.016 0.6 1.6
//! ```
use std::path::Path;
use std::process::ExitCode;

use treacle::output::read_frame;
use treacle::report::coiling::{CoilSample, coil_rate, coil_sample, fold_rate, unwrap_angles};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize| args.get(i).and_then(|s| s.parse::<f64>().ok());
    let (Some(dir), Some(ax), Some(az), Some(y0), Some(y1)) =
        (args.first(), num(1), num(2), num(3), num(4))
    else {
        eprintln!("usage: coil_track DIR AXIS_X AXIS_Z Y0 Y1 [T0 T1]   (metres, seconds)");
        return ExitCode::from(1);
    };
    let window = (num(5).unwrap_or(0.0), num(6).unwrap_or(f64::INFINITY));
    let mut files: Vec<_> = match std::fs::read_dir(dir) {
        Ok(d) => d
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("frame_") && !n.ends_with(".tmp"))
            })
            .collect(),
        Err(e) => {
            eprintln!("{dir}: {e}");
            return ExitCode::from(1);
        }
    };
    files.sort();
    let mut samples: Vec<CoilSample> = Vec::new();
    for path in &files {
        let frame = match read_frame(Path::new(path)) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("{e}");
                return ExitCode::from(1);
            }
        };
        let points = frame
            .positions
            .iter()
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]);
        if let Some(s) = coil_sample(frame.time, points, [ax, az], (y0, y1), 10) {
            samples.push(s);
        }
    }
    let phi = unwrap_angles(&samples);
    println!("time_s,count,radius_mm,angle_turns");
    for (s, p) in samples.iter().zip(&phi) {
        println!(
            "{:.4},{},{:.3},{:.4}",
            s.time,
            s.count,
            s.radius * 1e3,
            p / std::f64::consts::TAU
        );
    }
    match coil_rate(&samples, window) {
        Some(r) => println!(
            "window {:.3}–{:.3} s: {} frames, mean radius {:.2} mm, Ω = {:.2} rad/s ({:.3} turns/s), {:.2} turns",
            window.0,
            window.1.min(samples.last().map_or(0.0, |s| s.time)),
            r.samples,
            r.mean_radius * 1e3,
            r.angular_frequency,
            r.angular_frequency / std::f64::consts::TAU,
            r.turns
        ),
        None => println!("fewer than 3 frames with particles in the band inside the window"),
    }
    match fold_rate(&samples, window) {
        Some(f) => println!(
            "folding along x: {} crossings of the mean position, period {:.3} s, amplitude {:.2} mm",
            f.crossings,
            f.period,
            f.amplitude * 1e3
        ),
        None => println!("folding along x: fewer than two crossings in the window"),
    }
    ExitCode::SUCCESS
}
