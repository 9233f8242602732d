//! `treacle snapshot` and `treacle::snapshot`: particles land where they should (cluster
//! centroids, equal aspect ratio, painter's order), the CLI writes a valid PNG from the frames
//! of `treacle run` (PLY and VTK), and bad input is an error with exit code 1, never a panic.
#![cfg(feature = "plot")]

use crate::common::{scratch, treacle};
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use treacle::output::{OutputError, ParticleFrame, read_frame, read_ply, write_vtk};
use treacle::plot::viridis;
use treacle::snapshot::{Snapshot, SnapshotError, SnapshotOptions, View, render_snapshot};

fn describe(o: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}\n--- stderr\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

// ---------------------------------------------------------------------------------------------
// Geometry of the picture (library API)

const SPACING: f32 = 0.005;

/// A 3×3×3 block of particles with spacing 5 mm centred on `centre`, all with field value
/// `value`.
fn cluster(f: &mut ParticleFrame, centre: [f32; 3], value: f32) {
    for i in -1..=1 {
        for j in -1..=1 {
            for k in -1..=1 {
                let d = [i, j, k].map(|n| n as f32 * SPACING);
                f.positions
                    .push([centre[0] + d[0], centre[1] + d[1], centre[2] + d[2]]);
                f.velocities.push([0.0; 3]);
                f.fields[0].1.push(value);
            }
        }
    }
}

/// Three clusters: A at the origin (value 0), B 0.2 m along +x (value 0.5), C 0.1 m along +y
/// (value 1), so each has its own exact viridis colour (0, 0.5 and 1 of the scale).
fn three_clusters() -> ParticleFrame {
    let mut f = ParticleFrame::new(0, 0.0).with_field("tag", Vec::new());
    cluster(&mut f, [0.0, 0.0, 0.0], 0.0);
    cluster(&mut f, [0.2, 0.0, 0.0], 0.5);
    cluster(&mut f, [0.0, 0.1, 0.0], 1.0);
    f
}

fn render(f: &ParticleFrame, view: View) -> Snapshot {
    let opts = SnapshotOptions {
        field: "tag".into(),
        view,
        ..Default::default()
    };
    render_snapshot(f, &opts).unwrap()
}

/// Number and centroid \[px\] of the pixels of exactly `colour` inside the plot area (the
/// colour bar shows the same colours, so it must be excluded).
fn blob(s: &Snapshot, t: f64) -> (usize, (f64, f64)) {
    let c = viridis(t);
    let want = [c.0, c.1, c.2];
    let a = s.plot_area;
    let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
    for y in a.y0..a.y1 {
        for x in a.x0..a.x1 {
            if s.canvas.pixel(x as u32, y as u32) == Some(want) {
                n += 1;
                sx += x as f64;
                sy += y as f64;
            }
        }
    }
    (n, (sx / n.max(1) as f64, sy / n.max(1) as f64))
}

#[test]
fn clusters_land_where_expected_with_equal_scales() {
    let s = render(&three_clusters(), View::Z);
    assert_eq!((s.canvas.width(), s.canvas.height()), (1024, 768));
    assert!((s.spacing.unwrap() - SPACING as f64).abs() < 1e-6);
    let (na, a) = blob(&s, 0.0);
    let (nb, b) = blob(&s, 0.5);
    let (nc, c) = blob(&s, 1.0);
    // Each cluster is a filled 3×3 block of circles, a few hundred pixels at least.
    assert!(na > 300 && nb > 300 && nc > 300, "{na} {nb} {nc}");
    println!(
        "A {a:?}  B {b:?}  C {c:?}  px/m {:.1}  radius {} px",
        s.pixels_per_metre, s.radius_px
    );
    // Circle centres are rounded to whole pixels and each blob's centroid averages symmetric
    // circles, so centroids are exact to about a pixel: 1.5 px tolerance.
    let tol = 1.5;
    // View z: +x is right, +y is up (pixel y grows downwards).
    assert!((b.1 - a.1).abs() < tol, "B not level with A: {a:?} {b:?}");
    assert!((c.0 - a.0).abs() < tol, "C not above A: {a:?} {c:?}");
    assert!(b.0 > a.0 && c.1 < a.1);
    // Equal scales: 0.2 m and 0.1 m, measured in pixels along different axes, keep their 2:1
    // ratio, and both match the reported pixels per metre.
    let (ab, ac) = (b.0 - a.0, a.1 - c.1);
    assert!((ab - 0.2 * s.pixels_per_metre).abs() < tol, "{ab}");
    assert!((ac - 0.1 * s.pixels_per_metre).abs() < tol, "{ac}");
    // The data fill the plot area horizontally (the wider extent): A's and B's centres sit
    // one margin (4 % of 0.21 m plus a radius) and one half block (5 mm) inside its edges.
    let inset = (0.04 * 0.21 + 0.55 * 0.005 + 0.005) * s.pixels_per_metre;
    let area = s.plot_area;
    assert!(
        (a.0 - area.x0 as f64 - inset).abs() < 2.0 * tol,
        "{a:?} {area:?}"
    );
    assert!(
        (area.x1 as f64 - b.0 - inset).abs() < 2.0 * tol,
        "{b:?} {area:?}"
    );
    // The circles' radius follows the particle spacing: 0.55 spacings.
    let expected_radius = 0.55 * SPACING as f64 * s.pixels_per_metre;
    assert!((s.radius_px as f64 - expected_radius).abs() <= 0.5);
}

#[test]
fn nearer_particles_hide_farther_ones() {
    let f = three_clusters();
    // View x looks along +x: A (x = 0) is in front of B (x = 0.2) on the same spot.
    let s = render(&f, View::X);
    assert!(blob(&s, 0.0).0 > 300);
    assert_eq!(blob(&s, 0.5).0, 0, "B drawn over A");
    let (_, a) = blob(&s, 0.0);
    let (_, c) = blob(&s, 1.0);
    assert!((c.0 - a.0).abs() < 1.5 && c.1 < a.1, "{a:?} {c:?}");
    // View y looks down along −y: C (y = 0.1) is in front of A (y = 0).
    let s = render(&f, View::Y);
    assert!(blob(&s, 1.0).0 > 300);
    assert_eq!(blob(&s, 0.0).0, 0, "A drawn over C");
    // Within a cluster too, against file order: the front layer (z = +5 mm, value 1) comes
    // first in the file, the two layers behind it (value 0) after; view z looks along −z, so
    // only the front layer may show.
    let mut f = ParticleFrame::new(0, 0.0).with_field("tag", Vec::new());
    cluster(&mut f, [0.0, 0.0, 0.0], 0.0);
    let mut order: Vec<usize> = (0..f.len()).collect();
    order.sort_by_key(|&i| f.positions[i][2] <= 0.0);
    let positions: Vec<[f32; 3]> = order.iter().map(|&i| f.positions[i]).collect();
    let tags: Vec<f32> = positions
        .iter()
        .map(|p| if p[2] > 0.0 { 1.0 } else { 0.0 })
        .collect();
    assert_eq!(tags[0], 1.0);
    f.positions = positions;
    f.fields[0].1 = tags;
    let s = render(&f, View::Z);
    assert!(blob(&s, 1.0).0 > 300);
    assert_eq!(blob(&s, 0.0).0, 0, "back layers drawn over the front one");
}

#[test]
fn every_view_draws_the_particles_deterministically() {
    let f = three_clusters();
    for view in View::ALL {
        let s = render(&f, view);
        let again = render(&f, view);
        assert_eq!(s.canvas, again.canvas, "{view}");
        let visible: usize = [0.0, 0.5, 1.0].iter().map(|&t| blob(&s, t).0).sum();
        assert!(visible > 300, "{view}: {visible} particle pixels");
    }
}

#[test]
fn unknown_field_and_empty_frame_are_errors() {
    let f = three_clusters();
    let opts = SnapshotOptions {
        field: "temperature".into(),
        ..Default::default()
    };
    match render_snapshot(&f, &opts) {
        Err(SnapshotError::UnknownField { available, .. }) => {
            assert_eq!(available, ["speed", "vx", "vy", "vz", "x", "y", "z", "tag"]);
        }
        other => panic!("{other:?}"),
    }
    let empty = ParticleFrame::new(0, 0.0);
    assert!(matches!(
        render_snapshot(&empty, &SnapshotOptions::default()),
        Err(SnapshotError::EmptyFrame { .. })
    ));
    let small = SnapshotOptions {
        width: 100,
        ..Default::default()
    };
    assert!(matches!(
        render_snapshot(&f, &small),
        Err(SnapshotError::TooSmall { .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// Command line on the output of `treacle run`

/// Runs the droplet scene for 2 frames into `dir` once per test that needs it.
fn droplet_frames(dir: &Path) -> PathBuf {
    let o = treacle(&[
        "run",
        "scenes/droplet.ron",
        "--frames",
        "2",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    dir.join("frame_00002.ply")
}

/// Decode a PNG file: (width, height, RGB bytes).
fn decode_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let bytes = fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "PNG signature");
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn distinct_colours(rgb: &[u8]) -> usize {
    let mut c: Vec<&[u8]> = rgb.chunks(3).collect();
    c.sort_unstable();
    c.dedup();
    c.len()
}

#[test]
fn cli_draws_frames_of_a_run() {
    let dir = scratch("cli");
    let frame = droplet_frames(&dir);
    let png = dir.join("pictures").join("droplet.png");
    let o = treacle(&[
        "snapshot",
        frame.to_str().unwrap(),
        "--out",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    let (w, h, rgb) = decode_png(&png);
    assert_eq!((w, h), (1024, 768));
    // Particles in viridis colours, text, axes, grid: far more than a handful of colours.
    let colours = distinct_colours(&rgb);
    assert!(colours > 20, "{colours} colours");
    // No temporary file is left next to the PNG.
    let names: Vec<_> = fs::read_dir(png.parent().unwrap()).unwrap().collect();
    assert_eq!(names.len(), 1);

    // Options, and the same frame as legacy VTK.
    let vtk = dir.join("frame_00002.vtk");
    write_vtk(&vtk, &read_ply(&frame).unwrap()).unwrap();
    let png2 = dir.join("iso.png");
    let o = treacle(&[
        "snapshot",
        vtk.to_str().unwrap(),
        "--out",
        png2.to_str().unwrap(),
        "--color",
        "density",
        "--view",
        "iso",
        "--size",
        "640x480",
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("640x480") && stdout.contains("density"),
        "{stdout}"
    );
    let (w, h, rgb) = decode_png(&png2);
    assert_eq!((w, h), (640, 480));
    assert!(distinct_colours(&rgb) > 20);
    fs::remove_dir_all(&dir).unwrap();
}

/// Runs `treacle snapshot ARGS`, expects exit code 1 and returns stderr.
fn snapshot_fails(args: &[&str]) -> String {
    let mut all = vec!["snapshot"];
    all.extend_from_slice(args);
    let o = treacle(&all);
    assert_eq!(o.status.code(), Some(1), "{}", describe(&o));
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn cli_bad_input_exits_with_1_and_a_clear_message() {
    let dir = scratch("errors");
    let frame = droplet_frames(&dir);
    let f = frame.to_str().unwrap();
    let png = dir.join("out.png");
    let out = png.to_str().unwrap();

    let e = snapshot_fails(&[f, "--out", out, "--color", "temperature"]);
    assert!(e.contains("unknown field \"temperature\""), "{e}");
    assert!(e.contains(f), "{e}");
    assert!(
        e.contains("available: speed, vx, vy, vz, x, y, z, density, pressure, material"),
        "{e}"
    );
    let e = snapshot_fails(&[f, "--out", out, "--view", "top"]);
    assert!(
        e.contains("unknown view \"top\" (expected x, y, z or iso)"),
        "{e}"
    );
    let e = snapshot_fails(&[f, "--out", out, "--size", "1024"]);
    assert!(e.contains("--size") && e.contains("WIDTHxHEIGHT"), "{e}");
    let e = snapshot_fails(&[f, "--out", out, "--size", "100x100"]);
    assert!(e.contains("too small"), "{e}");
    let missing = dir.join("frame_99999.ply");
    let e = snapshot_fails(&[missing.to_str().unwrap(), "--out", out]);
    assert!(e.contains("frame_99999.ply"), "{e}");
    let metrics = dir.join("metrics.csv");
    let e = snapshot_fails(&[metrics.to_str().unwrap(), "--out", out]);
    assert!(e.contains("is not a particle frame"), "{e}");

    // A truncated PLY: an error naming the file, no picture.
    let bytes = fs::read(&frame).unwrap();
    let cut = dir.join("cut.ply");
    fs::write(&cut, &bytes[..bytes.len() - 10]).unwrap();
    let e = snapshot_fails(&[cut.to_str().unwrap(), "--out", out]);
    assert!(e.contains("malformed PLY") && e.contains("cut.ply"), "{e}");
    assert!(!png.exists());
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn truncated_frames_are_errors_not_panics() {
    let dir = scratch("truncated");
    let frame = droplet_frames(&dir);
    let bytes = fs::read(&frame).unwrap();
    let vtk_path = dir.join("frame.vtk");
    write_vtk(&vtk_path, &read_frame(&frame).unwrap()).unwrap();
    let header = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    // Every cut inside the header and its first records, then a stride through the body.
    let cuts = (0..header + 200).chain((header + 200..bytes.len()).step_by(997));
    let cut = dir.join("cut.ply");
    for len in cuts {
        fs::write(&cut, &bytes[..len]).unwrap();
        match read_frame(&cut) {
            Err(OutputError::MalformedPly { path, .. }) => assert_eq!(path, cut),
            // Cuts inside the first line "ply\n" are not recognisable as PLY.
            Err(OutputError::UnrecognisedFrameFile { .. }) if len < 4 => {}
            other => panic!("cut at {len}: {other:?}"),
        }
    }
    // VTK cut inside a binary block.
    let vtk = fs::read(&vtk_path).unwrap();
    fs::write(&vtk_path, &vtk[..vtk.len() / 2]).unwrap();
    match read_frame(&vtk_path) {
        Err(e @ OutputError::MalformedVtk { .. }) => {
            assert!(e.to_string().contains("file ends inside"), "{e}")
        }
        other => panic!("{other:?}"),
    }
    fs::remove_dir_all(&dir).unwrap();
}
