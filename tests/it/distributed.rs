//! A scene split over ranks against the same scene in one process (ALGORITHM §12). The ranks
//! are threads of this process ([`ThreadComm`]); with the `mpi` feature (CI, `.ci/run`) the
//! same comparison also runs the CLI under `mpirun`.
use treacle::distributed::{DecompositionError, Partition, ThreadComm};
use treacle::output::read_frame;
use treacle::runner::ranks::{
    RanksSummary, check_supported, run_scene_on_ranks, run_scene_on_ranks_with,
};
use treacle::runner::{RunOptions, run_scene};
use treacle::scene::{Scene, load_scene};

use crate::common::{crate_dir, scratch};

fn scene(name: &str) -> Scene {
    load_scene(&crate_dir().join("scenes").join(name)).unwrap_or_else(|e| panic!("{e}"))
}

/// The scene file `name` with each `(from, to)` of `edits` replaced in its text.
fn scene_with(name: &str, edits: &[(&str, &str)]) -> Scene {
    let path = crate_dir().join("scenes").join(name);
    let mut text = std::fs::read_to_string(&path).unwrap();
    for (from, to) in edits {
        assert!(text.contains(from), "{name} has no `{from}`");
        text = text.replace(from, to);
    }
    treacle::scene::parse_scene_str(&text, &path, path.parent().unwrap()).unwrap()
}

/// Runs `scene` for `frames` frames on `n` thread ranks into `dir`.
fn run_on_threads(
    scene: &Scene,
    frames: u64,
    n: usize,
    dir: &std::path::Path,
) -> Vec<RanksSummary> {
    let opts = RunOptions {
        frames: Some(frames),
        replace: true,
        ..RunOptions::new(dir)
    };
    on_thread_ranks(n, |_, comm| {
        run_scene_on_ranks(scene, &opts, Box::new(comm), |_, _| {})
            .unwrap_or_else(|e| panic!("{e}"))
    })
}

/// `run(rank, comm)` on each of `n` thread ranks at once; the results in rank order.
fn on_thread_ranks<T: Send>(n: usize, run: impl Fn(usize, ThreadComm) -> T + Sync) -> Vec<T> {
    std::thread::scope(|sc| {
        let handles: Vec<_> = ThreadComm::group(n)
            .into_iter()
            .enumerate()
            .map(|(r, comm)| {
                let run = &run;
                sc.spawn(move || run(r, comm))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

/// `scene` for `frames` frames in one process into `scratch(name)`: the folder and its steps.
fn one_process(scene: &Scene, frames: u64, name: &str) -> (std::path::PathBuf, u64) {
    let dir = scratch(name);
    let summary = run_scene(
        scene.clone(),
        &RunOptions {
            frames: Some(frames),
            replace: true,
            ..RunOptions::new(&dir)
        },
        |_, _| {},
    )
    .unwrap();
    (dir, summary.steps)
}

/// `s` for `frames` frames in one process and on each rank count of `counts` (thread ranks),
/// compared by [`assert_matches`] (same steps; `check` looks at each run's rank summaries);
/// returns the one-process folder.
fn compare_on_ranks(
    s: &Scene,
    frames: u64,
    counts: &[usize],
    name: &str,
    check: impl Fn(usize, &[RanksSummary]),
) -> std::path::PathBuf {
    let (one, steps) = one_process(s, frames, &format!("distributed_{name}_one"));
    for &n in counts {
        let dir = scratch(&format!("distributed_{name}_{n}"));
        let ranks = run_on_threads(s, frames, n, &dir);
        assert_eq!(ranks[0].run.steps, steps, "{name}, {n} ranks: steps");
        check(n, &ranks);
        assert_matches(s, &one, &dir, frames, steps, &format!("{name}, {n} ranks"));
    }
    one
}

/// Some particle migrated between the ranks of a run.
fn migrated(n: usize, ranks: &[RanksSummary]) {
    let migrations: u64 = ranks.iter().map(|r| r.stats.migrations).sum();
    assert!(migrations > 0, "{n} ranks: no particle migrated");
}

/// The largest difference between the k-th smallest coordinates of two frames, over the three
/// axes: a lower bound of the largest displacement between matching particles that needs no
/// particle identity (the ranks write the particles in another order).
fn sorted_axis_difference(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    (0..3)
        .map(|k| {
            let sorted = |p: &[[f32; 3]]| {
                let mut v: Vec<f32> = p.iter().map(|x| x[k]).collect();
                v.sort_by(f32::total_cmp);
                v
            };
            sorted(a)
                .iter()
                .zip(sorted(b))
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max)
        })
        .fold(0.0, f32::max)
}

/// Frame `f` of the run folder `dir`: its index of parts (a run on ranks) or its PLY file (one
/// process, or ranks with `gather_frames`).
fn frame_file(dir: &std::path::Path, f: u64) -> std::path::PathBuf {
    let parts = dir.join(format!("frame_{f:05}.parts"));
    if parts.exists() {
        parts
    } else {
        dir.join(format!("frame_{f:05}.ply"))
    }
}

/// The droplet (falls, lands, spreads across rank boundaries) on 2 and 3 ranks: the same
/// particle count and total mass bit for bit at every frame, the same number of steps, and
/// positions within the rounding bound below; particles migrate.
#[test]
fn droplet_on_ranks_matches_one_process() {
    compare_on_ranks(&scene("droplet.ron"), 12, &[2, 3], "droplet", migrated);
}

/// The Martin & Moyce dam break with the grid pressure projection (ALGORITHM §5.4: a cell
/// pressure per liquid cell from a CG solve split over the ranks, §12) on 2 and 3 ranks,
/// split along x through the collapsing column and the front: as the droplet (120 steps:
/// 7.5e-8 and 8.9e-8 m against the bound of 7.2e-6 m). Over these steps the ranks and one
/// process find the same liquid cells at every step; at step 124 a particle within rounding
/// of a cell face makes one more cell liquid on 2 ranks, and from there the runs differ by the
/// solver's tolerance, not by rounding (ALGORITHM §12).
#[test]
fn projected_dam_break_on_ranks_matches_one_process() {
    let s = projected_dam_break();
    compare_on_ranks(&s, 12, &[2, 3], "projected_dam_break", |n, ranks| {
        migrated(n, ranks);
        // The boundaries cut the liquid (the column is x < 0.1 m, 5 block layers of 4 cells).
        assert!(
            ranks[0].columns.end < 5,
            "{n} ranks: {:?}",
            ranks[0].columns
        );
    });
}

/// A velocity gradient carried from the last G2P (`velocity_gradient: Carried`, the game
/// presets' choice) is the next step's stress input, so it travels with a migrating particle:
/// the projected dam break made viscous (2 Pa s) matches one process. Without it a migrated
/// particle started its next step with L = 0 (2 ranks: 2.3e-5 m against the bound of 7.2e-6 m).
#[test]
fn a_carried_velocity_gradient_travels_with_its_particle() {
    let s = scene_with(
        "dam_break.ron",
        &[
            (
                "    dx: 0.005,",
                "    integrator: (scheme: SymplecticEuler, pressure: Projection(()), \
                 velocity_gradient: Carried),\n    dx: 0.005,",
            ),
            ("viscosity: 0.001", "viscosity: 2.0"),
        ],
    );
    compare_on_ranks(&s, 12, &[2, 3], "carried_gradient", migrated);
}

/// The projected dam break of [`projected_dam_break_on_ranks_matches_one_process`].
fn projected_dam_break() -> Scene {
    scene_with(
        "dam_break.ron",
        &[(
            "    dx: 0.005,",
            "    integrator: (scheme: SymplecticEuler, pressure: Projection(())),\n    dx: 0.005,",
        )],
    )
}

/// A rank's grid nodes with mass: (node, new velocity).
type NodeVelocities = Vec<([i32; 3], glam::Vec3)>;

/// The grid after the last step of `frames` frames of `s` on each of `n` thread ranks: per
/// rank its nodes with mass; the run's steps and rank 0's repartitions.
fn last_grids(s: &Scene, frames: u64, n: usize, name: &str) -> (u64, u64, Vec<NodeVelocities>) {
    use bevy_ecs::prelude::*;
    use treacle::grid::MpmGrid;
    use treacle::schedule::{GridUpdateSystems, MpmStep, StepContext};
    let dir = scratch(&format!("distributed_{name}_{n}"));
    let opts = RunOptions {
        frames: Some(frames),
        replace: true,
        ..RunOptions::new(&dir)
    };
    let runs = on_thread_ranks(n, |_, comm| {
        let store = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let out = store.clone();
        let record = move |grid: Res<MpmGrid>, ctx: Res<StepContext>| {
            if ctx.rate_evaluation {
                return;
            }
            let mut nodes = out.lock().unwrap();
            nodes.clear();
            for (i, node) in grid.nodes.iter().enumerate() {
                if node.mass > grid.mass_epsilon {
                    let c = grid.node_of_index(i).to_array();
                    nodes.push((c, glam::Vec3::from(node.new_velocity)));
                }
            }
        };
        let configure = |app: &mut bevy_app::App| {
            app.add_systems(MpmStep, record.after(GridUpdateSystems::Update));
        };
        let summary = run_scene_on_ranks_with(s, &opts, Box::new(comm), configure, |_, _| {})
            .unwrap_or_else(|e| panic!("{e}"));
        let nodes = std::mem::take(&mut *store.lock().unwrap());
        (summary.run.steps, summary.stats.rebalances, nodes)
    });
    let _ = std::fs::remove_dir_all(&dir);
    let (steps, rebalances) = (runs[0].0, runs[0].1);
    (steps, rebalances, runs.into_iter().map(|r| r.2).collect())
}

/// The node velocities after the pressure projection of the projected dam break's last step
/// on 2, 3 and 4 ranks against one rank, node by node (a shared node on both ranks that hold
/// it), after 3 frames and after 11 frames (past the first repartition of every split). The
/// bound is the rounding of [`assert_matches`] in velocity: one f32 unit in the last place per
/// step, relative to the largest node speed V, steps · ε · V (2.1e-6 m/s after the 30 steps of
/// 3 frames, 2.0e-5 m/s after 110 steps; measured at most 2.0e-7 and 1.2e-6). Each of the
/// split solve's exchanges left out (the shared layer's particles, the neighbours' corner
/// nodes, the node sums per operator application or their last two layers, the band's partial
/// means, the far layer's copy) moves some node by 4.8e-5 to 0.35 m/s after 3 frames; the
/// last pressures not handed to a cell's new owner, by 5.5e-4 m/s after 11. Without the
/// band's partial means (a far-layer copy instead) 4 ranks were off by 6.0e-4 m/s after 11
/// frames. (Both runs keep the same liquid cells over these steps; ALGORITHM §12 on when they
/// do not.)
#[test]
fn the_projection_on_ranks_gives_the_one_process_node_velocities() {
    let s = projected_dam_break();
    for frames in [3, 11] {
        let (steps, _, mut one) = last_grids(&s, frames, 1, "projected_nodes");
        let one: std::collections::HashMap<[i32; 3], glam::Vec3> =
            one.remove(0).into_iter().collect();
        let speed = one.values().map(|v| v.length()).fold(0.0, f32::max);
        let bound = steps as f32 * f32::EPSILON * speed;
        for n in [2, 3, 4] {
            let what = format!("{frames} frames, {n} ranks");
            let (ranks_steps, rebalances, grids) = last_grids(&s, frames, n, "projected_nodes");
            assert_eq!(ranks_steps, steps, "{what}: steps");
            if frames > 3 {
                assert!(rebalances > 0, "{what}: no repartition");
            }
            for (r, nodes) in grids.iter().enumerate() {
                for (c, v) in nodes {
                    let w = one
                        .get(c)
                        .unwrap_or_else(|| panic!("{what}, rank {r}: node {c:?}"));
                    let d = (*v - *w).length();
                    assert!(
                        d <= bound,
                        "{what}, rank {r}, node {c:?}: {v} against {w} ({d:e} m/s, bound \
                         {bound:e})"
                    );
                }
            }
        }
    }
}

/// The comparison of [`droplet_on_ranks_matches_one_process`] for a run of `s` that wrote
/// `dir`; with heat also the temperatures, phases and thermal metrics.
fn assert_matches(
    s: &Scene,
    one: &std::path::Path,
    dir: &std::path::Path,
    frames: u64,
    steps: u64,
    what: &str,
) {
    // Rounding: a shared node's two addends are summed in another order than in one process
    // (and a heat scene's thermal contributions in another order), a relative change of at
    // most one f32 ulp per step in the grid state; over `steps` steps a position can drift by
    // at most steps · ε · L (L the domain's largest extent: 0.3 m for the droplet) and a
    // temperature by steps · ε · T_s (T_s the run's temperature scale; the heat solve's CG,
    // preconditioned on ranks by each rank's own multigrid, stops at a relative residual of
    // 1e-8 in f64, far below). A missing halo or a lost
    // particle moves particles by a fraction of Δx in one step, and a lost heat contribution
    // changes temperatures by a fraction of T_s.
    let c = &s.config;
    let extent = (c.domain_max - c.domain_min).max_element();
    let bound = steps as f32 * f32::EPSILON * extent;
    let heat = s.thermal.as_ref().map(|t| {
        let scale = t.config.temperature_scale() as f32;
        (steps as f32 * f32::EPSILON * scale, scale)
    });
    let melting: Vec<f32> = s
        .phase_change
        .iter()
        .map(|(_, p)| p.melting_temperature)
        .collect();
    for f in [1, frames / 2, frames] {
        let a = read_frame(&frame_file(one, f)).unwrap();
        let b = read_frame(&frame_file(dir, f)).unwrap();
        assert_eq!(a.len(), b.len(), "{what}, frame {f}: particle count");
        let d = sorted_axis_difference(&a.positions, &b.positions);
        assert!(
            d <= bound,
            "{what}, frame {f}: positions differ by {d:e} m (bound {bound:e} m)"
        );
        let Some((t_bound, _)) = heat else { continue };
        let (ta, tb) = (
            a.field("temperature").unwrap(),
            b.field("temperature").unwrap(),
        );
        let dt = sorted_difference(ta, tb);
        assert!(
            dt <= t_bound,
            "{what}, frame {f}: temperatures differ by {dt:e} (bound {t_bound:e})"
        );
        if let (Some(pa), Some(pb)) = (a.field("phase"), b.field("phase")) {
            // Only a particle within the temperature bound of a melting point can be in
            // another phase.
            let near = ta
                .iter()
                .filter(|t| melting.iter().any(|m| (*t - m).abs() <= t_bound))
                .count();
            let melted = |p: &[f32]| p.iter().filter(|&&i| i < 0.5).count();
            let (ma, mb) = (melted(pa), melted(pb));
            assert!(
                ma.abs_diff(mb) <= near,
                "{what}, frame {f}: {ma} against {mb} melted particles ({near} near T_m)"
            );
        }
    }
    let metrics = |dir: &std::path::Path| {
        let text = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
        let mut lines = text.lines();
        let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
        let rows: Vec<Vec<String>> = lines
            .map(|l| l.split(',').map(String::from).collect())
            .collect();
        (header, rows)
    };
    let ((ha, ra), (hb, rb)) = (metrics(one), metrics(dir));
    assert_eq!(ha, hb, "{what}: metrics.csv columns");
    assert_eq!(ra.len(), rb.len(), "{what}: metrics.csv rows");
    let col = |name: &str| ha.iter().position(|h| h == name).unwrap();
    for (x, y) in ra.iter().zip(&rb) {
        for name in ["frame", "steps", "particles", "mass"] {
            assert_eq!(
                x[col(name)],
                y[col(name)],
                "{what}: {name} of frame {}",
                x[0]
            );
        }
        // A rigid body's position: the same rounding bound as the particles'.
        for (k, h) in ha.iter().enumerate() {
            if h.starts_with("rigid") && ["_x", "_y", "_z"].iter().any(|e| h.ends_with(e)) {
                let d = (x[k].parse::<f64>().unwrap() - y[k].parse::<f64>().unwrap()).abs();
                assert!(
                    d <= bound as f64,
                    "{what}: {h} of frame {} differs by {d:e} (bound {bound:e})",
                    x[0]
                );
            }
        }
        let Some((t_bound, _)) = heat else { continue };
        for name in ["t_min", "t_max", "t_mean"] {
            let v = |r: &[String]| r[col(name)].parse::<f64>().unwrap();
            let d = (v(x) - v(y)).abs();
            assert!(
                d <= t_bound as f64,
                "{what}: {name} of frame {} differs by {d:e} (bound {t_bound:e})",
                x[0]
            );
        }
    }
}

/// The droplet (12 frames) and the melting bunny (6 frames, heat and phase change) under
/// `mpirun -n 2` (each rank writes its part of a frame) and `-n 3 … --gather` (rank 0 writes
/// whole frames) with the `mpi` build of the CLI, against one process (CI installs Open MPI;
/// `--allow-run-as-root` because CI runs as root).
#[cfg(feature = "mpi")]
#[test]
fn scenes_under_mpirun_match_one_process() {
    for (name, frames) in [("droplet.ron", 12), ("bunny_melting_1.ron", 6)] {
        let s = scene(name);
        let (one, steps) = one_process(&s, frames, &format!("mpirun_one_{name}"));
        for n in [2, 3] {
            let dir = scratch(&format!("mpirun_{n}_{name}"));
            let o = std::process::Command::new("mpirun")
                .args([
                    "--allow-run-as-root",
                    "--oversubscribe",
                    "-n",
                    &n.to_string(),
                ])
                .arg(env!("CARGO_BIN_EXE_treacle"))
                .arg("run")
                .arg(format!("scenes/{name}"))
                .args(["--threads", "1", "--force", "--frames"])
                .arg(frames.to_string())
                .args((n == 3).then_some("--gather"))
                .arg("--out")
                .arg(&dir)
                .current_dir(crate_dir())
                .output()
                .expect("mpirun (Open MPI) is installed");
            let out = String::from_utf8_lossy(&o.stdout);
            assert!(
                o.status.success(),
                "{out}\n{}",
                String::from_utf8_lossy(&o.stderr)
            );
            let migrations: u64 = out
                .lines()
                .filter_map(|l| l.split(", ").find(|p| p.ends_with("migrations sent")))
                .map(|p| p.split(' ').next().unwrap().parse::<u64>().unwrap())
                .sum();
            assert_eq!(out.matches("block layers").count(), n, "{out}");
            assert!(
                migrations > 0,
                "{name}, {n} ranks: no particle migrated\n{out}"
            );
            let index = dir.join(format!("frame_{frames:05}.parts"));
            assert_eq!(
                index.exists(),
                n == 2,
                "{name}, {n} ranks: {}",
                index.display()
            );
            assert_matches(
                &s,
                &one,
                &dir,
                frames,
                steps,
                &format!("{name}, mpirun -n {n}"),
            );
        }
    }
}

/// [Su21]'s melting bunny (heat, phase change, 5 400 particles) on 2 and 3 ranks, until it has
/// melted (0.3 s): positions, temperatures, phases and the thermal metrics match one process
/// within the rounding bounds of [`assert_matches`]; particles (with their temperatures and
/// phase state) migrate.
#[test]
fn melting_bunny_on_ranks_matches_one_process() {
    let s = scene("bunny_melting_1.ron");
    let one = compare_on_ranks(&s, 9, &[2, 3], "melting", migrated);
    // It did melt: the last frame's melted fraction (last column) is above one half.
    let text = std::fs::read_to_string(one.join("metrics.csv")).unwrap();
    let last = text.lines().last().unwrap().rsplit(',').next().unwrap();
    let last: f64 = last.parse().unwrap();
    assert!(last > 0.5, "melted fraction {last}");
}

/// The melting bunny's heat solve is split, not replicated: on 1, 2 and 3 thread ranks, after
/// each frame, every rank has solved as often as one process, its unknowns (the Interior
/// lattice nodes it owns) are a part of the one-process count, and the parts add up to it
/// exactly (the node classes depend on the nodal masses only, which each rank sums completely
/// for the nodes it holds); the ranks agree on the CG iterations (their reductions are
/// collective). The iteration counts are printed (the rank-local multigrid could need more
/// than one process's; measured: the same).
#[test]
fn the_heat_solve_is_split_between_the_ranks() {
    use std::sync::{Arc, Mutex};
    use treacle::runner::ranks::run_scene_on_ranks_with;
    use treacle::thermal::ThermalStats;
    let s = scene("bunny_melting_1.ron");
    // Per rank, per frame: (solves, unknowns of the last solve, total CG iterations).
    type Log = Arc<Mutex<Vec<(u64, usize, u64)>>>;
    let run = |n: usize| -> Vec<Vec<(u64, usize, u64)>> {
        let dir = scratch(&format!("distributed_split_heat_{n}"));
        let opts = RunOptions {
            frames: Some(3),
            replace: true,
            ..RunOptions::new(&dir)
        };
        let logs: Vec<Log> = (0..n).map(|_| Log::default()).collect();
        on_thread_ranks(n, |r, comm| {
            let log = logs[r].clone();
            let record = move |app: &mut bevy_app::App| {
                app.add_systems(
                    bevy_app::Last,
                    move |st: bevy_ecs::prelude::Res<ThermalStats>| {
                        log.lock().unwrap().push((
                            st.solves,
                            st.last_unknowns,
                            st.total_iterations,
                        ));
                    },
                );
            };
            run_scene_on_ranks_with(&s, &opts, Box::new(comm), record, |_, _| {})
                .unwrap_or_else(|e| panic!("{e}"))
        });
        logs.iter().map(|l| l.lock().unwrap().clone()).collect()
    };
    let one = run(1).remove(0);
    assert!(one.len() >= 3 && one.last().unwrap().0 > 100, "{one:?}");
    for n in [2, 3] {
        let ranks = run(n);
        for (f, &(solves, unknowns, iterations)) in one.iter().enumerate() {
            let parts: Vec<usize> = ranks.iter().map(|r| r[f].1).collect();
            for r in &ranks {
                assert_eq!(r[f].0, solves, "{n} ranks, frame {f}: solves");
                assert_eq!(
                    r[f].2, ranks[0][f].2,
                    "{n} ranks, frame {f}: CG iterations differ"
                );
            }
            if unknowns > 0 {
                assert!(
                    parts.iter().all(|&p| p < unknowns),
                    "{n} ranks, frame {f}: unknowns {parts:?} of {unknowns}: not split"
                );
            }
            assert_eq!(
                parts.iter().sum::<usize>(),
                unknowns,
                "{n} ranks, frame {f}: unknowns {parts:?} against {unknowns}"
            );
            eprintln!(
                "{n} ranks, frame {f}: unknowns {parts:?} of {unknowns}; CG iterations {} \
                 against {iterations} in one process",
                ranks[0][f].2
            );
        }
    }
}

/// The XPP bunny (a rheology model with particle state, f64 polymer stress) on 2 and 3 ranks:
/// it falls, lands across rank boundaries and matches one process within the bounds of
/// [`assert_matches`]; particles migrate with their polymer stress.
#[test]
fn viscoelastic_bunny_on_ranks_matches_one_process() {
    compare_on_ranks(&scene("bunny_impact.ron"), 12, &[2, 3], "xpp", migrated);
}

/// [Su21]'s printing scene (a nozzle emitter, heat, phase change, an XPP paste on a bed
/// collider) on 2 and 3 ranks: every rank runs the nozzle and spawns the particles it owns;
/// the beads match one process within the bounds of [`assert_matches`].
#[test]
fn printing_on_ranks_matches_one_process() {
    // And with a driven bore of two particle spacings (D21) on 2 ranks: its particles refer to
    // their emitter, which travels as the emitter's place in spawn order. The bored bead is
    // sensitive: measured, the ranks' rounding differences (Σx over the particles: 1e-9 m
    // after 600 steps) grow about tenfold every 1,000 steps (1e-4 m after 6,000), beyond the
    // linear bound of `assert_matches`; so this compares the first 0.02 s (frames of 5 ms,
    // about 2,300 steps), in which the bore's particles have crossed between the ranks (from
    // step ≈ 700 on).
    let bored = scene_with(
        "printing.ron",
        &[
            ("jitter: 0.1,", "jitter: 0.1, bore: 0.0005,"),
            ("frame_rate: 20.0,", "frame_rate: 200.0,"),
        ],
    );
    compare_on_ranks(&bored, 4, &[2], "bore", migrated);
    // Every rank holds some of the printed particles.
    let some_on_each = |n: usize, ranks: &[RanksSummary]| {
        let counts: Vec<usize> = ranks.iter().map(|r| r.particles).collect();
        assert!(counts.iter().all(|&c| c > 0), "{n} ranks: {counts:?}");
    };
    compare_on_ranks(&scene("printing.ron"), 4, &[2, 3], "printing", some_on_each);
}

/// [Su21]'s Coiling 1 (GS4 semi-implicit: the implicit viscous solve, a nozzle emitter with a
/// driven bore) on 2 and 3 ranks, split along y: the jet falls through the rank boundaries
/// and matches one process within the bounds of [`assert_matches`]. On ranks each shared node
/// is an unknown of the rank that counts it, its velocity is copied to the other before every
/// operator application and its force summed after, and the CG's inner products are summed
/// over the ranks; the Jacobi preconditioner is the same as in one process, so only rounding
/// differs (measured over 20 frames, 1,873 steps: at most 7.5e-8 m, against a bound of
/// 2.5e-5 m).
#[test]
fn coiling_on_ranks_matches_one_process() {
    let along_y = |n: usize, ranks: &[RanksSummary]| {
        assert!(ranks.iter().all(|r| r.axis == 1), "axis {}", ranks[0].axis);
        migrated(n, ranks);
    };
    compare_on_ranks(&scene("coiling_1.ron"), 8, &[2, 3], "coiling", along_y);
}

/// [Li]'s golf ball dropped into ketchup (a rigid body, a Herschel–Bulkley model), coarsened to
/// Δx = 2 cm to keep the test short, on 2 and 3 ranks: the domain is split along y, the ball
/// falls through the rank boundaries, every rank sums the momentum exchange of the nodes it
/// owns and the ranks add the sums, so every rank moves the ball alike; particles and the
/// ball's position match one process within the bounds of [`assert_matches`].
#[test]
fn golf_ball_on_ranks_matches_one_process() {
    let s = scene_with("li_golf_ketchup.ron", &[("dx: 0.01,", "dx: 0.02,")]);
    let along_y = |_: usize, ranks: &[RanksSummary]| {
        assert!(ranks.iter().all(|r| r.axis == 1), "axis {}", ranks[0].axis);
    };
    compare_on_ranks(&s, 6, &[2, 3], "golf", along_y);
}

/// A domain twice as tall as wide is split along y, its longest axis: the droplet falls from
/// one rank's layers into the others', and the result matches one process.
#[test]
fn tall_droplet_is_split_along_y() {
    let s = scene_with(
        "droplet.ron",
        &[
            ("max: (0.3, 0.3, 0.3)", "max: (0.3, 0.6, 0.3)"),
            ("center: (0.15, 0.15, 0.15)", "center: (0.15, 0.3, 0.15)"),
        ],
    );
    compare_on_ranks(&s, 12, &[2], "tall", |n, ranks| {
        assert!(ranks.iter().all(|r| r.axis == 1), "axis {}", ranks[0].axis);
        migrated(n, ranks);
    });
}

#[test]
fn the_decomposition_axis_is_the_longest_non_periodic_one() {
    use treacle::distributed::decomposition_axis;
    use treacle::math::Vec3;
    let cube = Vec3::splat(1.0);
    assert_eq!(decomposition_axis(cube, [false; 3]), Some(0));
    assert_eq!(
        decomposition_axis(Vec3::new(1.0, 2.0, 1.5), [false; 3]),
        Some(1)
    );
    assert_eq!(
        decomposition_axis(Vec3::new(1.0, 2.0, 1.5), [false, true, false]),
        Some(2)
    );
    assert_eq!(decomposition_axis(cube, [true; 3]), None);
}

/// Same scene, rank count and threads: the same bits in every file of a frame, its index and
/// each rank's part (the droplet; the melting bunny, whose heat solve is split between the
/// ranks).
#[test]
fn ranks_are_deterministic() {
    for (name, frames) in [("droplet.ron", 4), ("bunny_melting_1.ron", 3)] {
        let s = scene(name);
        let a = scratch(&format!("distributed_det_a_{name}"));
        let b = scratch(&format!("distributed_det_b_{name}"));
        run_on_threads(&s, frames, 2, &a);
        run_on_threads(&s, frames, 2, &b);
        for f in 0..=frames {
            let files = [
                format!("frame_{f:05}.parts"),
                format!("ranks/frame_{f:05}.rank0.ply"),
                format!("ranks/frame_{f:05}.rank1.ply"),
            ];
            for file in files {
                assert_eq!(
                    std::fs::read(a.join(&file)).unwrap(),
                    std::fs::read(b.join(&file)).unwrap(),
                    "{name}, {file}"
                );
            }
        }
    }
}

#[test]
fn more_ranks_than_blocks_is_refused() {
    let e = Partition::balanced(0, &[5, 0, 3], 4).unwrap_err();
    assert_eq!(
        e,
        DecompositionError::MoreRanksThanBlocks {
            ranks: 4,
            columns: 3
        }
    );
    assert!(e.to_string().contains("at most 3 ranks"), "{e}");
}

#[test]
fn partition_balances_particles_and_gives_every_rank_a_column() {
    let p = Partition::balanced(0, &[0, 0, 10, 10, 10, 10, 0, 0], 2).unwrap();
    assert_eq!((p.columns(0), p.columns(1)), (0..4, 4..8));
    // All particles in one column: the other ranks still own one column each.
    let p = Partition::balanced(0, &[0, 40, 0, 0], 3).unwrap();
    assert!((0..3).all(|r| !p.columns(r).is_empty()), "{p:?}");
    assert_eq!(p.columns(2).end, 4);
    for c in 0..4 {
        assert!(p.columns(p.owner(c)).contains(&c));
    }
}

#[test]
fn unsupported_scenes_are_refused_with_the_reason() {
    use treacle::config::{BoundaryCondition, DomainWalls, PressureSolve};
    let mut periodic = scene("droplet.ron");
    periodic.config.walls = DomainWalls::all(BoundaryCondition::Periodic);
    let e = check_supported(&periodic).unwrap_err();
    assert!(e.to_string().contains("periodic on all three axes"), "{e}");
    let mut projected = scene("droplet.ron");
    projected.config.integrator.scheme = treacle::config::Scheme::SymplecticEuler;
    projected.config.integrator.pressure = PressureSolve::Projection(Default::default());
    check_supported(&projected).unwrap();
    for ok in [
        "coiling_1.ron",
        "buckling_1.ron",
        "droplet.ron",
        "bunny_melting_1.ron",
        "cube_impact_2.ron",
        "li_golf_ketchup.ron",
        "printing.ron",
    ] {
        check_supported(&scene(ok)).unwrap();
    }
}

/// A particle component of the caller's own that does not travel between ranks.
#[derive(bevy_ecs::prelude::Component)]
struct Stays;

/// Particles carrying a component that is not registered to travel are refused before the run,
/// naming the component and how to register it.
#[test]
fn a_particle_component_that_does_not_travel_is_refused() {
    let s = scene("droplet.ron");
    let dir = scratch("distributed_stays");
    let opts = RunOptions {
        frames: Some(1),
        replace: true,
        ..RunOptions::new(&dir)
    };
    let comm = ThreadComm::group(1).pop().unwrap();
    let mark = |app: &mut bevy_app::App| {
        let world = app.world_mut();
        let particles: Vec<_> = world
            .query_filtered::<bevy_ecs::prelude::Entity, bevy_ecs::prelude::With<treacle::components::Particle>>()
            .iter(world)
            .collect();
        for e in particles {
            world.entity_mut(e).insert(Stays);
        }
    };
    let e =
        treacle::runner::ranks::run_scene_on_ranks_with(&s, &opts, Box::new(comm), mark, |_, _| {})
            .unwrap_err()
            .to_string();
    assert!(
        e.contains("Stays") && e.contains("distributed::travel"),
        "{e}"
    );
}

/// Records a failure on the rank it runs on once the simulation is past 2.5 frames.
fn fail_in_frame_three(
    clock: bevy_ecs::prelude::Res<treacle::step::schedule::SimulationClock>,
    config: bevy_ecs::prelude::Res<treacle::config::MpmConfig>,
    mut status: bevy_ecs::prelude::ResMut<treacle::failure::SimulationStatus>,
) {
    if clock.time > 2.5 * config.frame_dt && status.failure.is_none() {
        status.failure = Some(treacle::failure::FailureReport::global(
            "test",
            1.0,
            "a failure injected on rank 1",
        ));
    }
}

/// A failure on one rank stops every rank in the same step: rank 1 fails in frame 3, both
/// ranks return the failure (rank 0's names rank 1 and its reason), and the folder holds
/// frames 0–2 and their metrics rows only (no file of the failed step's frame).
#[test]
fn a_failing_rank_stops_every_rank_before_the_frame_is_written() {
    use bevy_ecs::schedule::IntoScheduleConfigs;
    use treacle::runner::RunError;
    use treacle::runner::ranks::run_scene_on_ranks_with;
    use treacle::step::schedule::{MonitorSystems, MpmStep};
    let s = scene("droplet.ron");
    let dir = scratch("distributed_fail");
    let opts = RunOptions {
        frames: Some(6),
        replace: true,
        ..RunOptions::new(&dir)
    };
    let results = on_thread_ranks(2, |r, comm| {
        let inject = move |app: &mut bevy_app::App| {
            if r == 1 {
                app.add_systems(MpmStep, fail_in_frame_three.in_set(MonitorSystems::Energy));
            }
        };
        run_scene_on_ranks_with(&s, &opts, Box::new(comm), inject, |_, _| {})
    });
    for (r, result) in results.iter().enumerate() {
        let Err(RunError::Failed(f)) = result else {
            panic!("rank {r}: {result:?}");
        };
        assert!(f.reason.contains("injected on rank 1"), "rank {r}: {f}");
        if r == 0 {
            assert!(f.reason.contains("rank 1 failed"), "rank 0: {f}");
        }
    }
    assert_complete_frames(&dir, 3);
}

/// The files in `dir` are those of a complete run on 2 ranks of frames `0..frames`: their
/// indexes, each rank's part of each, and metrics rows for them; no file of a later frame.
fn assert_complete_frames(dir: &std::path::Path, frames: u32) {
    let names = |d: &std::path::Path| {
        let mut files: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        files.sort();
        files
    };
    let mut top: Vec<String> = (0..frames).map(|f| format!("frame_{f:05}.parts")).collect();
    top.extend(["metrics.csv".to_owned(), "ranks".to_owned()]);
    assert_eq!(names(dir), top);
    let parts: Vec<String> = (0..frames)
        .flat_map(|f| (0..2).map(move |r| format!("frame_{f:05}.rank{r}.ply")))
        .collect();
    assert_eq!(names(&dir.join("ranks")), parts);
    for f in 0..frames {
        read_frame(&frame_file(dir, f as u64)).unwrap();
    }
    let rows = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    assert_eq!(rows.lines().count(), 1 + frames as usize, "{rows}");
}

/// A rank that cannot write its part of a frame stops every rank before the frame's index is
/// written, and the other rank removes its part: rank 1's part of frame 2 meets a folder in
/// its place; both ranks return the write error (rank 0's names rank 1), and the folder holds
/// the complete frames 0–1 and nothing of frame 2.
#[test]
fn a_part_that_cannot_be_written_leaves_no_partial_frame() {
    use treacle::runner::RunError;
    let s = scene("droplet.ron");
    let dir = scratch("distributed_part_fails");
    let opts = RunOptions {
        frames: Some(6),
        replace: true,
        ..RunOptions::new(&dir)
    };
    let results = on_thread_ranks(2, |r, comm| {
        run_scene_on_ranks(&s, &opts, Box::new(comm), |frame, _| {
            if r == 1 && frame == 1 {
                let blocker = dir.join("ranks/frame_00002.rank1.ply");
                std::fs::create_dir_all(blocker.join("in the way")).unwrap();
            }
        })
    });
    for (r, res) in results.iter().enumerate() {
        let e = match res {
            Err(e @ (RunError::Output(_) | RunError::Distributed(_))) => e.to_string(),
            other => panic!("rank {r}: {:?}", other.as_ref().map(|_| ())),
        };
        assert!(e.contains("frame_00002.rank1.ply"), "rank {r}: {e}");
        if r == 0 {
            assert!(e.starts_with("rank 1 failed: "), "rank 0: {e}");
        }
    }
    std::fs::remove_dir_all(dir.join("ranks/frame_00002.rank1.ply")).unwrap();
    assert_complete_frames(&dir, 2);
}

/// A run on ranks measures the same metrics as one process: at frame 0 the particles are the
/// same, so the sums differ only in their order (the grid volume's nodal sums at shared nodes
/// are added on their owner). Relative bound: the additions of the sums, at most 27 per
/// particle and node, each adding at most one f64 ε.
#[test]
fn metrics_on_ranks_match_one_process() {
    let s = scene("droplet.ron");
    let (one, _) = one_process(&s, 0, "distributed_metrics_one");
    let read = |dir: &std::path::Path| {
        treacle::output::MetricsTable::read(&dir.join("metrics.csv")).unwrap()
    };
    let a = read(&one);
    let particles = a.column("particles").unwrap()[0];
    let bound = 2.0 * 27.0 * particles * f64::EPSILON;
    for n in [2, 3] {
        for gather_frames in [false, true] {
            let dir = scratch(&format!("distributed_metrics_{n}_{gather_frames}"));
            let opts = RunOptions {
                frames: Some(0),
                replace: true,
                gather_frames,
                ..RunOptions::new(&dir)
            };
            on_thread_ranks(n, |_, comm| {
                run_scene_on_ranks(&s, &opts, Box::new(comm), |_, _| {}).unwrap()
            });
            let b = read(&dir);
            for name in ["particles", "mass", "volume", "kinetic_energy", "max_speed"] {
                let (x, y) = (a.column(name).unwrap()[0], b.column(name).unwrap()[0]);
                assert!(
                    (x - y).abs() <= bound * x.abs(),
                    "{n} ranks (gathered {gather_frames}): {name} {y} against {x} in one process"
                );
            }
            let expected = if gather_frames {
                "frame_00000.ply"
            } else {
                "frame_00000.parts"
            };
            let frame = read_frame(&dir.join(expected)).unwrap();
            assert_eq!(frame.len() as f64, particles);
            assert_eq!(
                sorted_axis_difference(
                    &frame.positions,
                    &read_frame(&one.join("frame_00000.ply")).unwrap().positions
                ),
                0.0
            );
        }
    }
}

/// When the ranks' particle counts drift beyond `REBALANCE_AT`, every rank moves to the same
/// new partition (balanced by the counts of all ranks); within it, nothing changes.
#[test]
fn ranks_rebalance_alike_when_their_counts_drift() {
    use treacle::distributed::Ranks;
    let layout = treacle::grid::GridLayout::new(
        treacle::math::Vec3::ZERO,
        treacle::math::Vec3::splat(0.3),
        0.01,
    );
    let columns = layout.blocks.x as usize;
    let start = Partition::balanced(0, &vec![1; columns], 2).unwrap();
    let half = columns as i32 / 2;
    assert_eq!(start.columns(0), 0..half);
    // Rank 0 holds 10 particles in each of its columns; rank 1 as many (not drifted) or 30
    // in each of its first three (drifted: 90 against 50, the most 1.29 × the mean).
    let counts = |r: usize, drifted: bool| {
        let mut c = vec![0u64; columns];
        if r == 0 {
            (0..half as usize).for_each(|k| c[k] = 10);
        } else if drifted {
            (half as usize..half as usize + 3).for_each(|k| c[k] = 30);
        } else {
            (half as usize..columns).for_each(|k| c[k] = 10);
        }
        c
    };
    for drifted in [false, true] {
        let partitions = on_thread_ranks(2, |r, comm| {
            let mut ranks = Ranks::new(Box::new(comm), start.clone(), Vec::new());
            let changed = ranks.rebalance(&layout, &counts(r, drifted));
            (changed, ranks.partition.clone())
        });
        assert_eq!(partitions[0], partitions[1], "drifted {drifted}");
        let (changed, p) = &partitions[0];
        assert_eq!(*changed, drifted);
        if drifted {
            // 140 particles, 70 each: rank 0 takes rank 1's first column (50 + 30 = 80 is
            // nearer 70 than 50 is).
            assert_eq!(p.columns(1).start, half + 1, "{p:?}");
        } else {
            assert_eq!(*p, start);
        }
    }
}

/// The largest difference between the k-th smallest values of two columns.
fn sorted_difference(a: &[f32], b: &[f32]) -> f32 {
    let sorted = |p: &[f32]| {
        let mut v = p.to_vec();
        v.sort_by(f32::total_cmp);
        v
    };
    sorted(a)
        .iter()
        .zip(sorted(b))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// A stop request (a signal) that reaches one rank only stops every rank after the same
/// complete frame: rank 1 is asked to stop after frame 2, both ranks return `Interrupted` after
/// 2 frames, and the folder holds frames 0–2 (the ranks' parts and rank 0's indexes) and their
/// metrics rows (the files of a complete run up to there), nothing of frame 3.
#[test]
fn a_stop_request_on_one_rank_stops_every_rank_after_the_same_frame() {
    use treacle::runner::RunError;
    use treacle::step::schedule::StopRequest;
    let s = scene("droplet.ron");
    let dir = scratch("distributed_stop");
    let results = on_thread_ranks(2, |r, comm| {
        let stop = StopRequest::default();
        let opts = RunOptions {
            frames: Some(6),
            replace: true,
            stop: Some(stop.clone()),
            ..RunOptions::new(&dir)
        };
        run_scene_on_ranks(&s, &opts, Box::new(comm), |frame, _| {
            if r == 1 && frame == 2 {
                stop.flag().store(true, std::sync::atomic::Ordering::SeqCst);
            }
        })
    });
    for (r, res) in results.iter().enumerate() {
        match res {
            Err(RunError::Interrupted { frames, .. }) => assert_eq!(*frames, 2, "rank {r}"),
            other => panic!("rank {r}: {:?}", other.as_ref().map(|_| ())),
        }
    }
    assert_complete_frames(&dir, 3);
}

/// The grid volume Σᵢ mᵢ²/Σ w m ρ is nonlinear in the nodal sums: on ranks the sums at a node
/// both sides of a rank boundary reach are added on the node's owner before the division.
/// Particles across the boundaries with a density that varies along the split axis (so that
/// summing each rank's m²/Σ w m ρ separately would give another volume) measure the same
/// metrics on 2 and 3 thread ranks as in one process, within the rounding bound of
/// [`metrics_on_ranks_match_one_process`].
#[test]
fn grid_volume_on_ranks_adds_shared_nodes_before_dividing() {
    use treacle::components::{Density, Mass, Particle, Position, Velocity};
    use treacle::config::MpmConfig;
    use treacle::diagnostics::{MetricsScratch, measure_particles};
    use treacle::distributed::{Ranks, owner_at};
    use treacle::grid::GridLayout;
    use treacle::math::Vec3;
    use treacle::runner::ranks::measure_on_ranks;
    let config = MpmConfig::default();
    let layout = GridLayout::new(config.domain_min, config.domain_max, config.dx);
    let h = 0.5 * config.dx;
    let particles: Vec<(Vec3, f32)> = (0..80)
        .flat_map(|i| (0..20).flat_map(move |j| (0..20).map(move |k| (i, j, k))))
        .map(|(i, j, k)| {
            let x = Vec3::new(0.1 + h * i as f32, 0.4 + h * j as f32, 0.4 + h * k as f32);
            (x, 1000.0 + 3000.0 * x.x)
        })
        .collect();
    let (mass, speed) = (1e-3, Vec3::new(0.1, 0.0, 0.0));
    let one = measure_particles(&layout, &mut MetricsScratch::default(), || {
        particles.iter().map(|&(x, rho)| (x, speed, mass, rho))
    });
    let bound = 2.0 * 27.0 * particles.len() as f64 * f64::EPSILON;
    for n in [2, 3] {
        let partition = Partition::balanced(0, &vec![1; layout.blocks.x as usize], n).unwrap();
        let owned: Vec<usize> = (0..n)
            .map(|r| {
                particles
                    .iter()
                    .filter(|(x, _)| owner_at(&partition, &layout, *x) == r)
                    .count()
            })
            .collect();
        assert!(owned.iter().all(|&c| c > 0), "{n} ranks: {owned:?}");
        let measured = on_thread_ranks(n, |r, comm| {
            let mut world = bevy_ecs::world::World::new();
            world.insert_resource(config.clone());
            for &(x, rho) in &particles {
                if owner_at(&partition, &layout, x) == r {
                    world.spawn((
                        Particle,
                        Position(x),
                        Velocity(speed),
                        Mass(mass),
                        Density {
                            value: rho,
                            rate: 0.0,
                        },
                    ));
                }
            }
            world.insert_resource(Ranks::new(Box::new(comm), partition.clone(), Vec::new()));
            measure_on_ranks(&mut world, &mut MetricsScratch::default())
        });
        for (r, (_, per_rank)) in measured.iter().enumerate() {
            let counts: Vec<u64> = owned.iter().map(|&c| c as u64).collect();
            assert_eq!(*per_rank, counts, "{n} ranks, rank {r}: particles per rank");
        }
        let measured: Vec<_> = measured.into_iter().map(|(m, _)| m).collect();
        for (r, m) in measured.iter().enumerate() {
            assert_eq!(m.particles, one.particles, "{n} ranks, rank {r}");
            for (name, a, b) in [
                ("mass", one.mass, m.mass),
                ("volume", one.volume, m.volume),
                ("particle volume", one.particle_volume, m.particle_volume),
                ("kinetic energy", one.kinetic_energy, m.kinetic_energy),
                (
                    "centre of mass x",
                    one.center_of_mass[0],
                    m.center_of_mass[0],
                ),
            ] {
                assert!(
                    (a - b).abs() <= bound * a.abs(),
                    "{n} ranks, rank {r}: {name} {b} against {a} in one process"
                );
            }
        }
    }
}
