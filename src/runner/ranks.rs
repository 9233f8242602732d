//! [`run_scene_on_ranks`]: `treacle run` on several ranks. Every rank loads the scene,
//! spawns the particles of its columns ([`own_part`]) and steps them. At each output frame
//! every rank writes its own particles (`ranks/frame_NNNNN.rankR.ply`) and, once all parts are
//! written, rank 0 writes the frame's index `frame_NNNNN.parts`, which
//! [`crate::output::read_frame`] opens as the whole frame ([`crate::output::parts`]); with
//! [`RunOptions::gather_frames`] rank 0 gathers every rank's particles (in rank order) and
//! writes the frame as one file instead. The metrics are summed over the ranks
//! ([`measure_on_ranks`]) and rank 0 alone writes `metrics.csv`.
use bevy_ecs::prelude::*;

use crate::components::{Density, Mass, Particle, Position, Velocity, VelocityGradient};
use crate::config::{MpmConfig, VelocityGradientSource};
use crate::diagnostics::{MetricsColumns, MetricsScratch, StateMetrics, particle_sums};
use crate::distributed::{
    Communicator, DecompositionError, Partition, RankStats, Ranks, agree_on_failure,
    check_particle_components, decomposition_axis, f64_at, first_problem, keep_own_particles,
    layout_of, migrate_particles, owner_at, particles_per_column, push_f64s, travel,
};
use crate::grid::GridLayout;
use crate::math::Vec3;
use crate::output::{
    FramePart, MetricsWriter, OutputFormat, ParticleFrame, PartsIndex, index_file_name,
    part_file_name, write_frame, write_frame_part, write_parts_index,
};
use crate::runner::{
    RunError, RunOptions, RunSummary, check_memory, metrics_row_of, prepare_output_dir, scene_app,
    snapshot,
};
use crate::scene::Scene;
use crate::step::schedule::{
    MonitorSystems, MpmStep, PredictSystems, SimulationClock, StopRequest,
};

/// What a distributed run did, on this rank.
#[derive(Clone, Debug, Default)]
pub struct RanksSummary {
    /// The run (files are listed on rank 0 only).
    pub run: RunSummary,
    /// This rank's counts.
    pub stats: RankStats,
    /// The decomposition axis (0 x, 1 y, 2 z).
    pub axis: usize,
    /// The block layers along it this rank owned at the end.
    pub columns: std::ops::Range<i32>,
    /// Particles on this rank at the end.
    pub particles: usize,
    /// Wall time of the steps (the frames' `App::update`s, communication included) \[s\].
    pub step_seconds: f64,
    /// Wall time of the frames' output on this rank (packing, the gather to rank 0, and on
    /// rank 0 the frame files and metrics rows) \[s\].
    pub output_seconds: f64,
}

/// The features of `scene` the distributed step does not support, if any: a domain periodic on
/// all three axes (no axis to split).
pub fn check_supported(scene: &Scene) -> Result<(), DecompositionError> {
    if scene.config.walls.periodic_axes().iter().all(|p| *p) {
        return Err(DecompositionError::Unsupported(
            "a domain periodic on all three axes has no axis to split (run it in one process)"
                .into(),
        ));
    }
    Ok(())
}

/// Every rank's `result`: the first error (in rank order) on all of them, so that no rank goes
/// on alone into a collective.
fn agree(comm: &dyn Communicator, result: Result<(), String>) -> Result<(), String> {
    match first_problem(result.err().as_deref(), |w| comm.all_gather(w)) {
        None => Ok(()),
        Some((r, text)) if r == comm.rank() => Err(text),
        Some((r, text)) => Err(format!("rank {r} failed: {text}")),
    }
}

/// How `scene` splits over `ranks` ranks: the partition of its block layers along the
/// decomposition axis by its particles, and the nodes of the mirror faces normal to that axis.
/// Every rank computes the same.
pub fn partition_scene(
    scene: &Scene,
    ranks: usize,
) -> Result<(Partition, Vec<i32>), DecompositionError> {
    let config = &scene.config;
    let axis = decomposition_axis(
        config.domain_max - config.domain_min,
        config.walls.periodic_axes(),
    )
    .ok_or_else(|| {
        DecompositionError::Unsupported("a domain periodic on all three axes".to_owned())
    })?;
    let layout = GridLayout::new(config.domain_min, config.domain_max, config.dx);
    let positions = scene
        .particles
        .iter()
        .flat_map(|b| b.positions.iter().copied());
    let mut per_column = particles_per_column(&layout, axis, positions);
    for (c, n) in emitted_per_column(scene, &layout, axis)
        .into_iter()
        .enumerate()
    {
        per_column[c] += n;
    }
    let partition = Partition::balanced(axis, &per_column, ranks)?;
    let faces: Vec<i32> = crate::step::p2g::mirror_faces(config, &layout)
        .iter()
        .filter(|f| f.axis == axis)
        .map(|f| f.node)
        .collect();
    partition.check_walls(&layout, &faces)?;
    Ok((partition, faces))
}

/// Samples of the emitters' deposits over the scene's duration.
const EMITTER_SAMPLES: usize = 256;

/// The particles `scene`'s emitters deposit over its duration, per block layer along `axis`:
/// each emitter's expected count spread over its nozzle tip's positions at
/// [`EMITTER_SAMPLES`] times while it extrudes (the partition of an emitter scene then follows
/// where the liquid will be; the rebalancing follows where it goes).
fn emitted_per_column(scene: &Scene, layout: &GridLayout, axis: usize) -> Vec<u64> {
    let mut out = vec![0u64; layout.blocks[axis] as usize];
    let duration = scene.duration;
    for e in &scene.emitters {
        let total = e.volume_rate * e.extruding_time(duration) / f64::from(e.spacing).powi(3);
        let tips: Vec<Vec3> = (0..EMITTER_SAMPLES)
            .map(|i| (i as f64 + 0.5) / EMITTER_SAMPLES as f64 * duration)
            .filter(|&t| e.extrudes_at(t))
            .map(|t| e.path.sample(t - e.start_time).0.as_vec3())
            .collect();
        let each = (total / tips.len().max(1) as f64).round() as u64;
        for (c, n) in particles_per_column(layout, axis, tips.into_iter())
            .into_iter()
            .enumerate()
        {
            out[c] += n * each;
        }
    }
    out
}

/// `scene` with only the particles rank `rank` owns under `partition` (each rank spawns only
/// its own part).
pub fn own_part(scene: &Scene, partition: &Partition, rank: usize) -> Scene {
    let c = &scene.config;
    let layout = GridLayout::new(c.domain_min, c.domain_max, c.dx);
    let mut own = scene.clone();
    for body in &mut own.particles {
        body.positions
            .retain(|&x| owner_at(partition, &layout, x) == rank);
    }
    own
}

/// Adds the distributed systems to this rank's app (built from [`own_part`]) and makes `comm`
/// its [`Ranks`] with `split` ([`partition_scene`]); particles of other ranks the app holds are
/// dropped.
pub fn distribute(
    app: &mut bevy_app::App,
    comm: Box<dyn Communicator>,
    (partition, faces): (Partition, Vec<i32>),
) -> Result<(), DecompositionError> {
    let world = app.world_mut();
    // A velocity gradient carried from the last G2P is state, not scratch: the next step's
    // stress reads it.
    let carried = world.get_resource::<MpmConfig>().is_some_and(|c| {
        c.integrator.velocity_gradient == VelocityGradientSource::Carried
            && !c.integrator.scheme.is_gs4()
    });
    if carried {
        travel::<VelocityGradient>(world);
    }
    check_particle_components(world)?;
    if let Some(key) = MetricsColumns::not_across_ranks(world).first() {
        return Err(DecompositionError::Unsupported(format!(
            "its `{key}` metrics columns are not combined across ranks yet"
        )));
    }
    world.insert_resource(Ranks::new(comm, partition, faces));
    keep_own_particles(world);
    app.add_systems(
        MpmStep,
        (
            migrate_particles.in_set(PredictSystems::Migrate),
            agree_on_failure.in_set(MonitorSystems::Agree),
        ),
    );
    Ok(())
}

/// Words per gathered particle: position, velocity and the output fields.
fn particle_words(fields: usize) -> usize {
    6 + fields
}

/// This rank's particles as words for rank 0.
fn pack_frame(snap: &ParticleFrame) -> Vec<u32> {
    let mut out = Vec::with_capacity(snap.len() * particle_words(snap.fields.len()));
    for i in 0..snap.len() {
        out.extend(snap.positions[i].map(f32::to_bits));
        out.extend(snap.velocities[i].map(f32::to_bits));
        out.extend(snap.fields.iter().map(|(_, col)| col[i].to_bits()));
    }
    out
}

/// Rank 0's frame from every rank's packed particles, in rank order.
fn unpack_frame(scene: &Scene, frame: u32, time: f64, parts: &[Vec<u32>]) -> ParticleFrame {
    let nf = scene.output.fields.len();
    let stride = particle_words(nf);
    let mut out = ParticleFrame::new(frame, time);
    let mut cols = vec![Vec::new(); nf];
    let f = f32::from_bits;
    for w in parts.iter().flat_map(|p| p.chunks_exact(stride)) {
        out.positions.push([f(w[0]), f(w[1]), f(w[2])]);
        out.velocities.push([f(w[3]), f(w[4]), f(w[5])]);
        for (k, col) in cols.iter_mut().enumerate() {
            col.push(f(w[6 + k]));
        }
    }
    for (field, col) in scene.output.fields.iter().zip(cols) {
        out.push_field(field.name(), col);
    }
    out
}

/// Words per node of the metrics' nodal sums a rank sends to the node's owner: the node's
/// coordinates and the two f64 sums.
const METRICS_NODE_WORDS: usize = 7;

/// The metrics of the particles of every rank ([`crate::diagnostics::measure`] of the whole
/// run), on every rank (every rank calls this together). Each rank sums over its particles;
/// the nodal sums of the grid volume at nodes of another rank's columns go to that rank and
/// are added there in rank order before the nonlinear Σᵢ mᵢ²/Σ w m ρ over each rank's own
/// nodes; the ranks' sums are then added in rank order. Same ranks, same bits. Also returns
/// each rank's particle count (rank order).
pub fn measure_on_ranks(
    world: &mut World,
    scratch: &mut MetricsScratch,
) -> (StateMetrics, Vec<u64>) {
    let layout = layout_of(world);
    let mut q = world.query_filtered::<(&Position, &Velocity, &Mass, &Density), With<Particle>>();
    q.update_archetypes(world);
    let (q, w) = (&q, &*world);
    let mut m = particle_sums(&layout, scratch, || {
        q.iter_manual(w)
            .map(|(x, v, mass, rho)| (x.0, v.0, mass.0, rho.value))
    });
    let ranks = world.resource::<Ranks>();
    let p = &ranks.partition;
    let mut send = vec![Vec::new(); ranks.size()];
    let boxed = scratch.layout().expect("particle_sums sets the node box");
    let (mass, mass_rho) = scratch.nodal_sums_mut();
    for (idx, (mi, mr)) in mass.iter_mut().zip(mass_rho.iter_mut()).enumerate() {
        if *mi == 0.0 {
            continue;
        }
        let node = boxed.node_of_index(idx);
        let owner = p.owner(p.column_of(&layout, node));
        if owner != ranks.rank() {
            let out = &mut send[owner];
            out.extend(node.to_array().map(|c| c as u32));
            push_f64s(out, [*mi, *mr]);
            (*mi, *mr) = (0.0, 0.0);
        }
    }
    // The other ranks' sums at this rank's nodes, added in rank order into a box that covers
    // them too.
    let received = ranks.exchange(send);
    let nodes = received
        .iter()
        .flat_map(|words| words.chunks_exact(METRICS_NODE_WORDS))
        .map(|w| glam::IVec3::from_array([w[0], w[1], w[2]].map(|c| c as i32)));
    scratch.widen(nodes);
    let boxed = scratch.layout().expect("particle_sums sets the node box");
    let (mass, mass_rho) = scratch.nodal_sums_mut();
    for w in received
        .iter()
        .flat_map(|words| words.chunks_exact(METRICS_NODE_WORDS))
    {
        let node = glam::IVec3::from_array([w[0], w[1], w[2]].map(|c| c as i32));
        let idx = boxed.index(node);
        mass[idx] += f64_at(&w[3..], 0);
        mass_rho[idx] += f64_at(&w[3..], 1);
    }
    m.volume = scratch.grid_volume();
    let mine = [
        m.particles as f64,
        m.mass,
        m.volume,
        m.particle_volume,
        m.kinetic_energy,
        m.max_speed,
        m.center_of_mass[0],
        m.center_of_mass[1],
        m.center_of_mass[2],
    ];
    let mut all = StateMetrics::default();
    let mut per_rank = Vec::with_capacity(ranks.size());
    for v in ranks.all_gather(&mine) {
        per_rank.push(v[0] as u64);
        all.particles += v[0] as u64;
        all.mass += v[1];
        all.volume += v[2];
        all.particle_volume += v[3];
        all.kinetic_energy += v[4];
        all.max_speed = all.max_speed.max(v[5]);
        for (c, x) in all.center_of_mass.iter_mut().zip(&v[6..9]) {
            *c += x;
        }
    }
    all.finish_center_of_mass();
    (all, per_rank)
}

/// Writes this rank's particles as its part of `frame` ([`write_frame_part`]).
fn write_own_part(
    world: &mut World,
    scene: &Scene,
    dir: &std::path::Path,
    frame: u32,
    format: OutputFormat,
) -> Result<FramePart, RunError> {
    let rank = world.resource::<Ranks>().rank();
    let snap = snapshot(world, frame, &scene.output.fields);
    Ok(write_frame_part(dir, &snap, format, rank)?)
}

/// Removes this rank's part of `frame` if it was written (a frame some part or the index of
/// which could not be written leaves no file behind).
fn remove_own_part(dir: &std::path::Path, format: OutputFormat, frame: u32, rank: usize) {
    let path = dir.join(part_file_name(format, frame, rank));
    if path.exists() {
        // Best effort: the run stops with the write error that led here.
        let _ = std::fs::remove_file(path);
    }
}

/// Every rank's outcome of writing a frame (rank 0 writes): an error on rank 0 (a full disk)
/// stops every rank, not only rank 0 while the others wait in the next step's collectives.
fn agree_on_output(ranks: &Ranks, written: Result<(), RunError>) -> Result<(), RunError> {
    let mine = written.as_ref().err().map(ToString::to_string);
    let first = first_problem(mine.as_deref(), |w| ranks.all_gather_words(w));
    written?;
    match first {
        None => Ok(()),
        Some((r, text)) => Err(RunError::Distributed(format!("rank {r} failed: {text}"))),
    }
}

/// Runs `scene` on the ranks of `comm` (every rank calls this with the same arguments): the
/// one-process [`crate::runner::run_scene`] with the particles split over the ranks. Rank 0
/// writes the frames and `metrics.csv`; a failure on any rank stops every rank with its
/// report, before the frame it happened in is written. A [`RunOptions::stop`] request on any
/// rank stops every rank after the same complete frame ([`RunError::Interrupted`]).
pub fn run_scene_on_ranks(
    scene: &Scene,
    opts: &RunOptions,
    comm: Box<dyn Communicator>,
    on_frame: impl FnMut(u64, u64),
) -> Result<RanksSummary, RunError> {
    run_scene_on_ranks_with(scene, opts, comm, |_| {}, on_frame)
}

/// [`run_scene_on_ranks`] with `configure` applied to this rank's app before it is split
/// (plugins, systems, resources of the caller's own).
pub fn run_scene_on_ranks_with(
    scene: &Scene,
    opts: &RunOptions,
    comm: Box<dyn Communicator>,
    configure: impl FnOnce(&mut bevy_app::App),
    mut on_frame: impl FnMut(u64, u64),
) -> Result<RanksSummary, RunError> {
    let wall0 = std::time::Instant::now();
    let comm_rank = comm.rank();
    let root = comm_rank == 0;
    let setup = check_supported(scene)
        .map_err(|e| e.to_string())
        .and_then(|()| check_memory(scene, opts.max_memory).map_err(|e| e.to_string()))
        .and_then(|()| {
            if root {
                prepare_output_dir(&opts.out_dir, opts.replace).map_err(|e| e.to_string())
            } else {
                Ok(())
            }
        });
    agree(&*comm, setup).map_err(RunError::Distributed)?;
    let split =
        partition_scene(scene, comm.size()).map_err(|e| RunError::Distributed(e.to_string()))?;
    let mut app = scene_app(&own_part(scene, &split.0, comm_rank));
    configure(&mut app);
    distribute(&mut app, comm, split).map_err(|e| RunError::Distributed(e.to_string()))?;
    let total = opts.frames.unwrap_or_else(|| scene.frames());
    let format = opts.format.unwrap_or(match scene.output.format {
        crate::scene::OutputFormatSpec::Ply => OutputFormat::Ply,
        crate::scene::OutputFormatSpec::Vtk => OutputFormat::Vtk,
    });
    let every = scene.output.every.max(1) as u64;
    let extra = MetricsColumns::columns(app.world_mut());
    let names: Vec<&str> = extra.iter().map(String::as_str).collect();
    let mut metrics = if root {
        Some(MetricsWriter::new(&opts.out_dir).with_extra_columns(&names)?)
    } else {
        None
    };
    let mut scratch = MetricsScratch::default();
    let mut summary = RanksSummary::default();
    let (dir, rank) = (&opts.out_dir, comm_rank);
    // Writes frame `frame` if `write` (each rank its part and rank 0 the index, or rank 0 the
    // gathered frame) and rank 0 its metrics row. Every rank calls it together.
    let mut output = |app: &mut bevy_app::App,
                      frame: u64,
                      write: bool,
                      wall: f64,
                      summary: &mut RanksSummary|
     -> Result<(), RunError> {
        let frame = frame as u32;
        let world = app.world_mut();
        let per_rank = write && !opts.gather_frames;
        let part = if per_rank {
            let (written, part) = match write_own_part(world, scene, dir, frame, format) {
                Ok(part) => (Ok(()), Some(part)),
                Err(e) => (Err(e), None),
            };
            // Every part is written before the index: a failure on any rank stops all (and
            // `output_agreed` removes the parts written).
            agree_on_output(world.resource::<Ranks>(), written)?;
            part
        } else {
            None
        };
        let gathered = if write && opts.gather_frames {
            let snap = snapshot(world, frame, &scene.output.fields);
            let ranks = world.resource::<Ranks>();
            let mut send = vec![Vec::new(); ranks.size()];
            send[0] = pack_frame(&snap);
            Some(ranks.exchange(send))
        } else {
            None
        };
        let (m, per_rank) = measure_on_ranks(world, &mut scratch);
        let extra_parts = MetricsColumns::rank_parts(world);
        let extra_parts = world.resource::<Ranks>().all_gather(&extra_parts);
        // Every rank's part: its path and particle count (the count its part holds: the
        // particles it measured).
        let parts = part.map(|_| {
            per_rank
                .iter()
                .enumerate()
                .map(|(r, &n)| FramePart {
                    path: part_file_name(format, frame, r),
                    particles: n as usize,
                })
                .collect::<Vec<_>>()
        });
        let Some(metrics) = metrics.as_mut() else {
            return Ok(());
        };
        let time = world.resource::<SimulationClock>().time;
        if let Some(parts) = parts {
            let index = PartsIndex { frame, time, parts };
            summary.run.files.push(write_parts_index(dir, &index)?);
        }
        if let Some(words) = gathered {
            let snap = unpack_frame(scene, frame, time, &words);
            summary.run.files.push(write_frame(dir, &snap, format)?);
        }
        let extra = MetricsColumns::combine_ranks(world, &extra_parts);
        let clock = world.resource::<SimulationClock>();
        let mut row = metrics_row_of(&m, clock, frame, wall);
        row.extra = extra;
        metrics.push(row)?;
        Ok(())
    };
    // Writes a frame and agrees on the outcome; a frame that failed on any rank leaves no
    // part behind.
    let mut output_agreed = |app: &mut bevy_app::App,
                             frame: u64,
                             write: bool,
                             wall: f64,
                             summary: &mut RanksSummary|
     -> Result<(), RunError> {
        let t = std::time::Instant::now();
        let written = output(app, frame, write, wall, summary);
        summary.output_seconds += t.elapsed().as_secs_f64();
        let agreed = agree_on_output(app.world().resource::<Ranks>(), written);
        if agreed.is_err() && write && !opts.gather_frames {
            remove_own_part(dir, format, frame as u32, rank);
            if root {
                // The index, if rank 0 wrote it before failing on its metrics row.
                let _ = std::fs::remove_file(dir.join(index_file_name(frame as u32)));
            }
        }
        agreed
    };
    output_agreed(&mut app, 0, true, 0.0, &mut summary)?;
    for frame in 1..=total {
        // A stop request (a signal) on any rank stops every rank before the same frame.
        let asked = opts.stop.as_ref().is_some_and(StopRequest::requested);
        let ranks = app.world().resource::<Ranks>();
        if first_problem(asked.then_some("stop"), |w| ranks.all_gather_words(w)).is_some() {
            let clock = app.world().resource::<SimulationClock>();
            return Err(RunError::Interrupted {
                frames: frame - 1,
                time: clock.time,
                steps: clock.steps,
                dir: opts.out_dir.clone(),
            });
        }
        let t = std::time::Instant::now();
        app.update();
        summary.step_seconds += t.elapsed().as_secs_f64();
        if let Some(f) = app
            .world()
            .resource::<crate::failure::SimulationStatus>()
            .failure
            .clone()
        {
            return Err(RunError::Failed(Box::new(f)));
        }
        let wall = wall0.elapsed().as_secs_f64();
        let write = frame % every == 0 || frame == total;
        output_agreed(&mut app, frame, write, wall, &mut summary)?;
        on_frame(frame, total);
        summary.run.frames = frame;
    }
    let world = app.world_mut();
    summary.run.steps = world.resource::<SimulationClock>().steps;
    summary.run.wall_seconds = wall0.elapsed().as_secs_f64();
    let ranks = world.resource::<Ranks>();
    summary.stats = ranks.stats();
    summary.columns = ranks.partition.columns(ranks.rank());
    summary.axis = ranks.partition.axis();
    summary.particles = world
        .query_filtered::<(), With<Particle>>()
        .iter(world)
        .count();
    Ok(summary)
}
