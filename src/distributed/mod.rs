//! One scene on several processes (*ranks*), decomposed over the sparse grid's blocks
//! (ALGORITHM §12).
//!
//! **Ownership.** The grid's block layers (*columns*) along the domain's longest non-periodic
//! axis are split into consecutive ranges, one per rank ([`Partition`]). A particle lives on
//! the rank that owns the column of its stencil's base block. Its stencil reaches its own
//! block column and the next one up, so a rank's particles reach its own columns and the first
//! column of the rank above; a column is reached by at most two ranks.
//!
//! **One step.** After Predict, particles whose stencil moved into another rank's columns
//! migrate there (all their components, bit for bit: [`migrate_particles`]). After every
//! scatter onto the grid (P2G's mass, momentum and m·a; the stress scatter's forces) the two
//! ranks that share a column send each other their sums of its allocated blocks and each adds
//! the other's ([`Ranks::sum_halo`]), before the mirror folds. A shared node then holds the
//! same two addends on both ranks, and a + b = b + a in floating point, so both hold the same
//! bits: the grid update, which is node-local, gives both the same new state, and the gathers
//! need no second exchange. The Δt rule's maxima, the failure checks, the energy monitor's
//! sums and P2G's mass threshold are agreed through collectives, summed in rank order.
//!
//! **Determinism.** Every exchange is ordered by rank; received particles are appended in
//! rank order. Same scene, rank count and threads → the same bits. Against one process the
//! sums at shared nodes and the energy sums are added in another order, so positions agree to
//! within f32 rounding grown over the run (the CI test states the bound it checks).
//!
//! **What runs distributed.** The explicit schemes with every material model (their particle
//! state travels: [`Travels`], [`travel`]), walls, colliders, rigid bodies (their momentum
//! exchange summed over the ranks, [`Ranks::counts_node`]), nozzle emitters (every rank runs
//! them and spawns the particles it owns) and heat with phase change (the thermal lattice is
//! split like the grid, with two ghost layers per neighbour; the conjugate gradients run on the
//! split vectors with a halo exchange per operator application and reductions over the
//! ranks, preconditioned by each rank's own multigrid: `thermal::solve::HeatHalo`), the
//! implicit viscous solve of the semi-implicit schemes (shared nodes are unknowns of the rank
//! that counts them: `SharedColumns::copy_counted_vector`, `SharedColumns::sum_halo_vector`), and the grid
//! pressure projection (cells are unknowns of one rank; the node sums of its operator are
//! completed with the neighbour's on the shared columns: `step::implicit::pressure`'s `halo`
//! module). A domain periodic on all three axes is refused with the reason
//! ([`crate::runner::ranks::check_supported`]).
//!
//! The transport is a [`Communicator`]: MPI with the `mpi` feature (`mpi_comm`), or
//! [`ThreadComm`], ranks as threads of one process (tests, and a machine without MPI).
use std::sync::{Arc, Barrier, Mutex};

use bevy_ecs::component::ComponentId;
use bevy_ecs::prelude::*;

use crate::components::{
    Acceleration, CauchyStress, DeformationGradient, Density, Mass, Particle, ParticleStencil,
    PhaseIndex, Position, PredictedDeformationGradient, PredictedDensity, StabilityData, Velocity,
    VelocityGradient,
};
use crate::grid::{BLOCK_NODES, GridLayout, GridNode, MpmGrid};
use crate::material::MaterialId;
use crate::math::{Mat3, Vec3};

#[cfg(feature = "mpi")]
pub mod mpi_comm;

/// The transport between ranks: one collective, an all-to-all of `u32` words.
pub trait Communicator: Send + Sync {
    /// This process's rank, `0..size()`.
    fn rank(&self) -> usize;
    /// Number of ranks.
    fn size(&self) -> usize;
    /// Sends `send[r]` to rank `r` (every rank calls this together) and returns what every
    /// rank sent to this one, indexed by sender.
    fn exchange(&self, send: Vec<Vec<u32>>) -> Vec<Vec<u32>>;

    /// Every rank's `words`, in rank order (every rank calls this together). The default goes
    /// through [`Communicator::exchange`]; MPI uses its all-gather (latency log P, not P).
    fn all_gather(&self, words: &[u32]) -> Vec<Vec<u32>> {
        self.exchange(vec![words.to_vec(); self.size()])
    }

    /// Sends `lower` to rank − 1 and `upper` to rank + 1 (nothing beyond the ends) and returns
    /// what they sent here, `(from rank − 1, from rank + 1)`. Every rank calls this together.
    /// The default goes through [`Communicator::exchange`]; MPI sends two messages.
    fn neighbour_exchange(&self, lower: Vec<u32>, upper: Vec<u32>) -> (Vec<u32>, Vec<u32>) {
        let (rank, size) = (self.rank(), self.size());
        let mut send = vec![Vec::new(); size];
        if rank > 0 {
            send[rank - 1] = lower;
        }
        if rank + 1 < size {
            send[rank + 1] = upper;
        }
        let mut got = self.exchange(send);
        let from_upper = if rank + 1 < size {
            std::mem::take(&mut got[rank + 1])
        } else {
            Vec::new()
        };
        let from_lower = if rank > 0 {
            std::mem::take(&mut got[rank - 1])
        } else {
            Vec::new()
        };
        (from_lower, from_upper)
    }
}

/// Ranks as threads of one process: [`ThreadComm::group`] makes `n` communicators that exchange
/// through shared memory. Same semantics as MPI's all-to-all.
pub struct ThreadComm {
    rank: usize,
    shared: Arc<ThreadShared>,
}

struct ThreadShared {
    /// `boxes[to][from]`.
    boxes: Mutex<Vec<Vec<Vec<u32>>>>,
    barrier: Barrier,
    size: usize,
}

impl ThreadComm {
    /// `n` communicators, rank `0..n`, to be moved to one thread each.
    pub fn group(n: usize) -> Vec<ThreadComm> {
        let shared = Arc::new(ThreadShared {
            boxes: Mutex::new(vec![vec![Vec::new(); n]; n]),
            barrier: Barrier::new(n),
            size: n,
        });
        (0..n)
            .map(|rank| ThreadComm {
                rank,
                shared: shared.clone(),
            })
            .collect()
    }
}

impl Communicator for ThreadComm {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.shared.size
    }
    fn exchange(&self, send: Vec<Vec<u32>>) -> Vec<Vec<u32>> {
        assert_eq!(send.len(), self.size(), "one message per rank");
        {
            let mut boxes = self.shared.boxes.lock().expect("a rank thread panicked");
            for (to, msg) in send.into_iter().enumerate() {
                boxes[to][self.rank] = msg;
            }
        }
        self.shared.barrier.wait();
        let n = self.size();
        let out = std::mem::replace(
            &mut self.shared.boxes.lock().expect("a rank thread panicked")[self.rank],
            vec![Vec::new(); n],
        );
        // Nobody writes the next round before everyone has read this one.
        self.shared.barrier.wait();
        out
    }
}

/// The block layers (*columns*) along the decomposition axis each rank owns: rank `r` owns
/// the blocks whose coordinate along [`Partition::axis`] lies in `starts[r]..starts[r + 1]`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Partition {
    axis: usize,
    starts: Vec<i32>,
}

/// Why a scene cannot run on the requested ranks.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecompositionError {
    /// More ranks than block layers along the decomposition axis.
    #[error(
        "{ranks} ranks but the grid has only {columns} block layers along the decomposition \
         axis (blocks of 4 cells): each rank must own at least one; run on at most {columns} \
         ranks"
    )]
    MoreRanksThanBlocks {
        /// Ranks asked for.
        ranks: usize,
        /// Block columns of the grid.
        columns: i32,
    },
    /// A rank boundary falls next to a mirror wall, where ghost and image nodes would be split.
    #[error(
        "the boundary between ranks {lower} and {} falls at block layer {column}, within two \
         nodes of a wall's mirror layers; run on fewer ranks",
        lower + 1
    )]
    BoundaryAtWall {
        /// The rank below the boundary.
        lower: usize,
        /// The shared column.
        column: i32,
    },
    /// A feature the distributed step does not support.
    #[error("this scene cannot run on several ranks: {0}")]
    Unsupported(String),
}

impl Partition {
    /// Splits `columns` block columns over `ranks` so that each holds about the same number of
    /// particles (`per_column[c]`: particles whose block is in column c), at least one column
    /// each; equal column ranges if there are no particles. Depends on the counts only.
    pub fn balanced(
        axis: usize,
        per_column: &[u64],
        ranks: usize,
    ) -> Result<Self, DecompositionError> {
        let columns = per_column.len() as i32;
        if ranks == 0 || ranks as i32 > columns {
            return Err(DecompositionError::MoreRanksThanBlocks { ranks, columns });
        }
        let total: u64 = per_column.iter().sum();
        if total == 0 {
            // No particles yet (an emitter scene): equal column ranges.
            return Self::balanced(axis, &vec![1; per_column.len()], ranks);
        }
        let mut starts = vec![0i32];
        let mut acc = 0u64;
        let mut c = 0i32;
        for r in 1..ranks {
            // First column whose cumulative count reaches r/ranks of the total, keeping one
            // column for this rank and one for each rank still to come.
            let target = (total as u128 * r as u128 / ranks as u128) as u64;
            let lo = starts[r - 1] + 1;
            let hi = columns - (ranks - r) as i32;
            while c < lo || (c < hi && acc + per_column[c as usize] <= target) {
                acc += per_column[c as usize];
                c += 1;
            }
            // The boundary nearer to the target: one column more if that is closer.
            if c < hi {
                let next = acc + per_column[c as usize];
                if next as i128 - (target as i128) < target as i128 - acc as i128 {
                    acc = next;
                    c += 1;
                }
            }
            starts.push(c.clamp(lo, hi));
        }
        starts.push(columns);
        Ok(Self { axis, starts })
    }

    /// The decomposition axis (0 x, 1 y, 2 z).
    pub fn axis(&self) -> usize {
        self.axis
    }

    /// The column of the block holding node `node`.
    pub fn column_of(&self, layout: &GridLayout, node: glam::IVec3) -> i32 {
        layout.block_of_node(node)[self.axis]
    }

    /// Number of ranks.
    pub fn ranks(&self) -> usize {
        self.starts.len() - 1
    }

    /// The columns rank `r` owns.
    pub fn columns(&self, r: usize) -> std::ops::Range<i32> {
        self.starts[r]..self.starts[r + 1]
    }

    /// The rank owning block column `c` (columns beyond the ends belong to the end ranks).
    pub fn owner(&self, c: i32) -> usize {
        self.starts[1..self.ranks()].partition_point(|&s| s <= c)
    }

    /// Checks that no rank boundary falls within two nodes of a mirror face normal to the axis
    /// (`faces`: their nodes along it), where a ghost and its image would sit on different
    /// ranks.
    pub fn check_walls(
        &self,
        layout: &GridLayout,
        faces: &[i32],
    ) -> Result<(), DecompositionError> {
        for r in 0..self.ranks() - 1 {
            let column = self.starts[r + 1];
            for &f in faces {
                let near = (f - 2..=f + 2).any(|n| {
                    let mut node = glam::IVec3::ZERO;
                    node[self.axis] = n;
                    self.column_of(layout, node) == column
                });
                if near {
                    return Err(DecompositionError::BoundaryAtWall { lower: r, column });
                }
            }
        }
        Ok(())
    }
}

/// Counts of what the decomposition did (reported after a run).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RankStats {
    /// Particles this rank sent to others.
    pub migrations: u64,
    /// Words (4 B) this rank sent in halo exchanges.
    pub halo_words: u64,
    /// Halo exchanges.
    pub halo_exchanges: u64,
    /// Repartitions ([`REBALANCE_AT`]).
    pub rebalances: u64,
    /// Exchanges (collective calls of the communicator).
    pub exchanges: u64,
    /// Wall time spent in the communicator's exchanges (sending, and waiting for the other
    /// ranks) \[s\].
    pub comm_seconds: f64,
}

/// The columns are repartitioned when the rank with the most particles holds more than this
/// multiple of the mean (1.25: a rank 25 % above the mean makes the others wait a quarter of
/// a step).
pub const REBALANCE_AT: f64 = 1.25;

/// This process's place in a distributed run (a resource; absent in a single-process run).
#[derive(Resource)]
pub struct Ranks {
    comm: Box<dyn Communicator>,
    /// Who owns which block columns.
    pub partition: Partition,
    /// What this rank sent.
    pub stats: Mutex<RankStats>,
    /// Nodes along the axis of the mirror faces normal to it (a rank boundary may not fall
    /// next to them).
    faces: Vec<i32>,
    /// The blocks the lower neighbour holds in this rank's first column (sorted; from the last
    /// P2G halo exchange): [`Ranks::counts_node`].
    lower_blocks: Mutex<Vec<[i32; 3]>>,
}

/// Which node fields a halo exchange sums.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HaloFields {
    /// P2G: mass, momentum, m·a.
    Transfer,
    /// The stress scatter: force.
    Force,
}

impl HaloFields {
    const fn words(self) -> usize {
        match self {
            HaloFields::Transfer => 7,
            HaloFields::Force => 3,
        }
    }

    fn pack(self, n: &GridNode, out: &mut Vec<u32>) {
        let v = |x: f32| x.to_bits();
        match self {
            HaloFields::Transfer => {
                out.push(v(n.mass));
                out.extend(n.velocity.to_array().map(v));
                out.extend(n.acceleration.to_array().map(v));
            }
            HaloFields::Force => out.extend(n.force.to_array().map(v)),
        }
    }

    fn add(self, n: &mut GridNode, w: &[u32]) {
        let f = |k: usize| f32::from_bits(w[k]);
        match self {
            HaloFields::Transfer => {
                n.mass += f(0);
                n.velocity += glam::Vec3A::new(f(1), f(2), f(3));
                n.acceleration += glam::Vec3A::new(f(4), f(5), f(6));
            }
            HaloFields::Force => n.force += glam::Vec3A::new(f(0), f(1), f(2)),
        }
    }
}

impl Ranks {
    /// This process's place: `comm` and the partition every rank computed alike.
    /// `faces`: the nodes of the mirror faces normal to the partition's axis
    /// ([`Partition::check_walls`]).
    pub fn new(comm: Box<dyn Communicator>, partition: Partition, faces: Vec<i32>) -> Self {
        assert_eq!(comm.size(), partition.ranks(), "one column range per rank");
        Self {
            comm,
            partition,
            stats: Mutex::new(RankStats::default()),
            faces,
            lower_blocks: Mutex::new(Vec::new()),
        }
    }

    /// This rank.
    pub fn rank(&self) -> usize {
        self.comm.rank()
    }

    /// Number of ranks.
    pub fn size(&self) -> usize {
        self.comm.size()
    }

    /// Whether this rank owns a particle at `x` before its first step (a particle spawned
    /// now: [`owner_at`]).
    pub fn owns(&self, layout: &GridLayout, x: Vec3) -> bool {
        owner_at(&self.partition, layout, x) == self.rank()
    }

    /// Whether this rank counts grid node `node` (one it holds) in a sum over nodes, so that
    /// every node with mass is counted by exactly one rank. A node of a column two ranks hold
    /// (halo-summed, the same bits on both) is counted by the lower rank if it holds the node's
    /// block, else by the upper one (the lower rank's blocks there are those it sent in the
    /// last P2G halo exchange).
    pub fn counts_node(&self, layout: &GridLayout, node: glam::IVec3) -> bool {
        let col = self.partition.column_of(layout, node);
        let own = self.partition.columns(self.rank());
        if col == own.end {
            return true;
        }
        if col != own.start || self.rank() == 0 {
            return own.contains(&col);
        }
        let b = layout.block_of_node(node).to_array();
        let lower = self.lower_blocks.lock().expect("lower blocks lock");
        lower.binary_search(&b).is_err()
    }

    /// The decomposition axis (0 x, 1 y, 2 z).
    pub fn axis(&self) -> usize {
        self.partition.axis
    }

    /// Whether this rank owns grid node `node` in a split heat solve: the node's block column
    /// is one of this rank's.
    pub fn owns_node(&self, layout: &GridLayout, node: glam::IVec3) -> bool {
        self.partition
            .columns(self.rank())
            .contains(&self.partition.column_of(layout, node))
    }

    /// Whether rank `rank` holds grid node `node` in a split heat solve: a node of its own
    /// columns, or of a neighbour's within two node layers of them (its ghosts: the reach of
    /// the Laplacian and of its particles' stencils, ALGORITHM §12).
    pub fn holds_node(&self, rank: usize, layout: &GridLayout, node: glam::IVec3) -> bool {
        let p = &self.partition;
        let own = p.columns(rank);
        [0, 2, -2].into_iter().any(|d| {
            let mut n = node;
            n[p.axis] += d;
            own.contains(&p.column_of(layout, n))
        })
    }

    /// Sends `lower` to rank − 1 and `upper` to rank + 1 (ignored where there is none) and
    /// returns what they sent here, `(from rank − 1, from rank + 1)`; counted as a halo
    /// exchange. Every rank calls it together.
    pub fn neighbour_exchange(&self, lower: Vec<u32>, upper: Vec<u32>) -> (Vec<u32>, Vec<u32>) {
        let (rank, size) = (self.rank(), self.size());
        let words =
            if rank > 0 { lower.len() } else { 0 } + if rank + 1 < size { upper.len() } else { 0 };
        let out = self.timed(|c| c.neighbour_exchange(lower, upper));
        let mut st = self.stats.lock().expect("stats lock");
        st.halo_words += words as u64;
        st.halo_exchanges += 1;
        out
    }

    /// What this rank sent so far.
    pub fn stats(&self) -> RankStats {
        *self.stats.lock().expect("stats lock")
    }

    /// Sends `send[r]` to rank `r`, returns what each rank sent here.
    pub fn exchange(&self, send: Vec<Vec<u32>>) -> Vec<Vec<u32>> {
        self.timed(|c| c.exchange(send))
    }

    /// Runs one collective of the communicator, counting it and its time.
    fn timed<T>(&self, f: impl FnOnce(&dyn Communicator) -> T) -> T {
        let t = std::time::Instant::now();
        let out = f(&*self.comm);
        let mut st = self.stats.lock().expect("stats lock");
        st.comm_seconds += t.elapsed().as_secs_f64();
        st.exchanges += 1;
        out
    }

    /// Repartitions the columns by `per_column` (this rank's particles per column) when the
    /// ranks' counts drift beyond [`REBALANCE_AT`] (every rank decides alike, from the counts of
    /// all). Returns whether the partition changed.
    pub fn rebalance(&mut self, layout: &GridLayout, per_column: &[u64]) -> bool {
        self.rebalance_and_flag(layout, per_column, false).0
    }

    /// [`Ranks::rebalance`], and whether `flag` is set on any rank (in the same collective).
    fn rebalance_and_flag(
        &mut self,
        layout: &GridLayout,
        per_column: &[u64],
        flag: bool,
    ) -> (bool, bool) {
        let mut mine: Vec<f64> = per_column.iter().map(|&c| c as f64).collect();
        mine.push(f64::from(u8::from(flag)));
        // Integer counts below 2^53: exact in f64, in any order.
        let mut total: Vec<u64> = self.sum(&mine).iter().map(|&c| c as u64).collect();
        let any_flag = total.pop().is_some_and(|f| f > 0);
        (self.repartition(layout, &total), any_flag)
    }

    /// Moves to the partition balanced by `total` (particles per column, all ranks) if the
    /// current one is out of balance ([`REBALANCE_AT`]).
    fn repartition(&mut self, layout: &GridLayout, total: &[u64]) -> bool {
        let size = self.size();
        let per_rank: Vec<u64> = (0..size)
            .map(|r| {
                let cols = self.partition.columns(r);
                total[cols.start as usize..cols.end as usize].iter().sum()
            })
            .collect();
        let mean = per_rank.iter().sum::<u64>() as f64 / size as f64;
        let most = per_rank.iter().copied().max().unwrap_or(0) as f64;
        if mean == 0.0 || most <= REBALANCE_AT * mean {
            return false;
        }
        let Ok(new) = Partition::balanced(self.partition.axis, total, size) else {
            return false;
        };
        if new == self.partition || new.check_walls(layout, &self.faces).is_err() {
            return false;
        }
        self.partition = new;
        self.stats.lock().expect("stats lock").rebalances += 1;
        true
    }

    /// Every rank's `words`, in rank order.
    pub fn all_gather_words(&self, words: &[u32]) -> Vec<Vec<u32>> {
        self.timed(|c| c.all_gather(words))
    }

    /// Every rank's `values` (the same length on every rank), in rank order.
    pub fn all_gather(&self, values: &[f64]) -> Vec<Vec<f64>> {
        let words: Vec<u32> = values
            .iter()
            .flat_map(|v| {
                let b = v.to_bits();
                [b as u32, (b >> 32) as u32]
            })
            .collect();
        self.timed(|c| c.all_gather(&words))
            .into_iter()
            .map(|w| {
                w.chunks_exact(2)
                    .map(|p| f64::from_bits(p[0] as u64 | ((p[1] as u64) << 32)))
                    .collect()
            })
            .collect()
    }

    /// Element-wise sums over the ranks, added in rank order.
    pub fn sum(&self, values: &[f64]) -> Vec<f64> {
        let all = self.all_gather(values);
        let mut out = vec![0.0; values.len()];
        for r in &all {
            for (o, v) in out.iter_mut().zip(r) {
                *o += v;
            }
        }
        out
    }

    /// Element-wise maxima over the ranks.
    pub fn max(&self, values: &[f64]) -> Vec<f64> {
        let all = self.all_gather(values);
        let mut out = vec![f64::NEG_INFINITY; values.len()];
        for r in &all {
            for (o, v) in out.iter_mut().zip(r) {
                *o = o.max(*v);
            }
        }
        out
    }

    /// Sums the allocated blocks of the columns this rank shares with its neighbours into both
    /// (module docs): call after a scatter onto `grid`, before its folds.
    pub fn sum_halo(&self, grid: &mut MpmGrid, fields: HaloFields) {
        let (rank, size) = (self.rank(), self.size());
        if size < 2 {
            return;
        }
        let own = self.partition.columns(rank);
        let axis = self.partition.axis;
        // The column shared with each neighbour: the lower's is my first, the upper's its first.
        let shared = |nb: usize| if nb < rank { own.start } else { own.end };
        // The allocated blocks of a column, in slot order.
        let slots_of = |grid: &MpmGrid, column: i32| -> Vec<usize> {
            let keys = grid.block_keys();
            (0..keys.len())
                .filter(|&s| grid.block_of_key(keys[s])[axis] == column)
                .collect()
        };
        // [to rank − 1, to rank + 1].
        let mut send = [Vec::new(), Vec::new()];
        let mut words = 0u64;
        for (side, nb) in [rank.wrapping_sub(1), rank + 1].into_iter().enumerate() {
            if nb >= size {
                continue;
            }
            let out = &mut send[side];
            for s in slots_of(grid, shared(nb)) {
                out.push(grid.block_keys()[s]);
                for n in &grid.nodes[s * BLOCK_NODES..(s + 1) * BLOCK_NODES] {
                    fields.pack(n, out);
                }
            }
            words += out.len() as u64;
        }
        let [lower, upper] = send;
        let (a, b) = self.timed(|c| c.neighbour_exchange(lower, upper));
        let received = [a, b];
        let stride = 1 + BLOCK_NODES * fields.words();
        if fields == HaloFields::Transfer {
            let mut lower: Vec<[i32; 3]> = received[0]
                .chunks_exact(stride)
                .map(|block| grid.block_of_key(block[0]).to_array())
                .collect();
            lower.sort_unstable();
            *self.lower_blocks.lock().expect("lower blocks lock") = lower;
        }
        for msg in &received {
            for block in msg.chunks_exact(stride) {
                let b = grid.block_of_key(block[0]);
                // Blocks this rank did not allocate: none of its particles reach them.
                let Some(s) = grid.slot_of_block(b) else {
                    continue;
                };
                let nodes = &mut grid.nodes[s * BLOCK_NODES..(s + 1) * BLOCK_NODES];
                for (n, w) in nodes
                    .iter_mut()
                    .zip(block[1..].chunks_exact(fields.words()))
                {
                    fields.add(n, w);
                }
            }
        }
        let mut st = self.stats.lock().expect("stats lock");
        st.halo_words += words;
        st.halo_exchanges += 1;
    }
}

impl Ranks {
    /// The allocated blocks of block column `column`, in slot order.
    fn slots_in_column(&self, grid: &MpmGrid, column: i32) -> Vec<usize> {
        let keys = grid.block_keys();
        (0..keys.len())
            .filter(|&s| grid.block_of_key(keys[s])[self.partition.axis] == column)
            .collect()
    }

    /// The allocated blocks of the columns this rank shares with its neighbours in `grid`, for
    /// the node-vector exchanges of a solve (found once: a solve's operator exchanges them at
    /// every application, and the blocks do not change from P2G to the end of the grid update).
    pub fn shared_columns(&self, grid: &MpmGrid) -> SharedColumns<'_> {
        let (rank, size) = (self.rank(), self.size());
        let own = self.partition.columns(rank);
        let slots = [
            if rank > 0 {
                self.slots_in_column(grid, own.start)
            } else {
                Vec::new()
            },
            if rank + 1 < size {
                self.slots_in_column(grid, own.end)
            } else {
                Vec::new()
            },
        ];
        SharedColumns { ranks: self, slots }
    }
}

/// The allocated blocks of the two block columns a rank shares ([`Ranks::shared_columns`]):
/// its first column (with rank − 1) and the column above its own (with rank + 1).
pub struct SharedColumns<'a> {
    ranks: &'a Ranks,
    /// Per side (0: with rank − 1, 1: with rank + 1): the column's slots in slot order (none
    /// without that neighbour).
    slots: [Vec<usize>; 2],
}

impl SharedColumns<'_> {
    /// The ranks.
    pub fn ranks(&self) -> &Ranks {
        self.ranks
    }

    /// Sends each neighbour the values of `v` (a vector over `grid`'s nodes, 3 f64 per node)
    /// on the shared blocks of the sides in `sides` (0: to rank − 1, 1: to rank + 1) and
    /// applies what arrives with `take(node value, received value)` on the blocks this rank
    /// holds.
    fn exchange_node_vector(
        &self,
        grid: &MpmGrid,
        v: &mut [glam::DVec3],
        sides: [bool; 2],
        take: impl Fn(&mut glam::DVec3, glam::DVec3),
    ) {
        let mut out = [Vec::new(), Vec::new()];
        for (side, msg) in out.iter_mut().enumerate() {
            if !sides[side] {
                continue;
            }
            for &s in &self.slots[side] {
                msg.push(grid.block_keys()[s]);
                push_f64s(
                    msg,
                    v[s * BLOCK_NODES..(s + 1) * BLOCK_NODES]
                        .iter()
                        .flat_map(|n| n.to_array()),
                );
            }
        }
        let [lower, upper] = out;
        let (a, b) = self.ranks.neighbour_exchange(lower, upper);
        let stride = 1 + 6 * BLOCK_NODES;
        for block in a.chunks_exact(stride).chain(b.chunks_exact(stride)) {
            let Some(s) = grid.slot_of_block(grid.block_of_key(block[0])) else {
                continue;
            };
            for (k, n) in v[s * BLOCK_NODES..(s + 1) * BLOCK_NODES]
                .iter_mut()
                .enumerate()
            {
                let w = &block[1..];
                take(
                    n,
                    glam::DVec3::new(f64_at(w, 3 * k), f64_at(w, 3 * k + 1), f64_at(w, 3 * k + 2)),
                );
            }
        }
    }

    /// [`Ranks::sum_halo`] for a vector over `grid`'s nodes (e.g. the forces of an implicit
    /// solve's operator): each rank adds its neighbours' partial sums of the columns they
    /// share, so both hold the same bits there.
    pub fn sum_halo_vector(&self, grid: &MpmGrid, v: &mut [glam::DVec3]) {
        if self.ranks.size() < 2 {
            return;
        }
        self.exchange_node_vector(grid, v, [true, true], |n, w| *n += w);
    }

    /// Copies the values of `v` (a vector over `grid`'s nodes) on the nodes of the shared
    /// columns this rank counts ([`Ranks::counts_node`]: the lower rank's blocks there) to the
    /// neighbour, which overwrites its copies: afterwards both hold the counting rank's values.
    pub fn copy_counted_vector(&self, grid: &MpmGrid, v: &mut [glam::DVec3]) {
        if self.ranks.size() < 2 {
            return;
        }
        self.exchange_node_vector(grid, v, [false, true], |n, w| *n = w);
    }
}

/// The reductions of a solve split over ranks ([`crate::krylov::Reduction`]): sums in rank
/// order, maxima with NaN propagated; the identity without ranks (one process).
#[derive(Clone, Copy)]
pub struct RankReduction<'a>(pub Option<&'a Ranks>);

impl crate::krylov::Reduction for RankReduction<'_> {
    fn sum(&self, local: f64) -> f64 {
        self.0.map_or(local, |r| r.sum(&[local])[0])
    }

    fn max(&self, local: f64) -> f64 {
        let Some(r) = self.0 else {
            return local;
        };
        r.all_gather(&[local])
            .iter()
            .map(|v| v[0])
            .fold(f64::NEG_INFINITY, max_nan)
    }

    fn sums_and_max(&self, sums: [f64; 2], max: f64) -> ([f64; 2], f64) {
        let Some(r) = self.0 else {
            return (sums, max);
        };
        let mut out = ([0.0; 2], f64::NEG_INFINITY);
        for v in r.all_gather(&[sums[0], sums[1], max]) {
            out.0[0] += v[0];
            out.0[1] += v[1];
            out.1 = max_nan(out.1, v[2]);
        }
        out
    }

    fn fuses(&self) -> bool {
        self.0.is_some()
    }
}

/// The larger of two values, NaN if either is.
fn max_nan(m: f64, v: f64) -> f64 {
    if v > m || v.is_nan() { v } else { m }
}

/// The components a particle carries in a distributed run, in the order they travel. The
/// per-step scratch components (`VelocityGradient`, `PredictedDensity`, `CauchyStress`,
/// `StabilityData`) are recomputed after the migration and do not travel (a carried velocity
/// gradient does, as a registered [`Travels`] component).
const PARTICLE_WORDS: usize = 3 + 3 + 3 + 1 + 2 + 1 + 3 + 3;

/// The travelling components of a particle, as a query reads them.
type Travelling<'a> = (
    &'a Position,
    &'a Velocity,
    &'a Acceleration,
    &'a Mass,
    &'a Density,
    &'a MaterialId,
    &'a ParticleStencil,
);

fn pack_particle(out: &mut Vec<u32>, (x, v, a, m, rho, id, st): Travelling<'_>) {
    let f = |x: f32| x.to_bits();
    out.extend(x.0.to_array().map(f));
    out.extend(v.0.to_array().map(f));
    out.extend(a.0.to_array().map(f));
    out.push(f(m.0));
    out.extend([f(rho.value), f(rho.rate)]);
    out.push(id.0 as u32);
    out.extend(st.base.to_array().map(|c| c as u32));
    out.extend(st.offset.to_array().map(f));
}

type ParticleParts = (
    Position,
    Velocity,
    Acceleration,
    Mass,
    Density,
    MaterialId,
    ParticleStencil,
);

fn unpack_particle(w: &[u32]) -> ParticleParts {
    let f = |k: usize| f32::from_bits(w[k]);
    let v3 = |k: usize| Vec3::new(f(k), f(k + 1), f(k + 2));
    (
        Position(v3(0)),
        Velocity(v3(3)),
        Acceleration(v3(6)),
        Mass(f(9)),
        Density {
            value: f(10),
            rate: f(11),
        },
        MaterialId(w[12] as u16),
        ParticleStencil {
            base: glam::IVec3::new(w[13] as i32, w[14] as i32, w[15] as i32),
            offset: v3(16),
        },
    )
}

/// A particle component that travels with its particle when the particle migrates to another
/// rank, as [`Travels::WORDS`] 32-bit words: bit patterns, so it arrives bit for bit. A plugin
/// whose particles carry state registers it with [`travel`]; a distributed run refuses
/// particles carrying a component that neither travels nor is per-step scratch
/// ([`check_particle_components`]).
pub trait Travels: Component + Sized {
    /// Words per component.
    const WORDS: usize;
    /// Appends the component's `WORDS` words to `out`.
    fn pack(&self, out: &mut Vec<u32>);
    /// The component from `words` (exactly `WORDS` of them, as [`Travels::pack`] wrote them).
    fn unpack(words: &[u32]) -> Self;
}

/// Packs `T` of `e` into `out` if `e` has one.
fn pack_component<T: Travels>(world: &World, e: Entity, out: &mut Vec<u32>) -> bool {
    world.get::<T>(e).map(|c| c.pack(out)).is_some()
}

/// Inserts `T` from `words` on `e`.
fn insert_component<T: Travels>(e: &mut EntityWorldMut<'_>, words: &[u32]) {
    e.insert(T::unpack(words));
}

/// One registered travelling component.
#[derive(Clone, Copy)]
struct Traveller {
    id: ComponentId,
    words: usize,
    pack: fn(&World, Entity, &mut Vec<u32>) -> bool,
    insert: fn(&mut EntityWorldMut<'_>, &[u32]),
}

/// The optional particle components that travel with a migration, in registration order (a
/// resource, filled by the plugins that add particle state: [`travel`]).
#[derive(Resource, Default, Clone)]
pub struct TravellingComponents {
    entries: Vec<Traveller>,
}

impl TravellingComponents {
    /// Number of registered components.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether none is registered.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Whether the component `id` is registered.
    pub fn contains(&self, id: ComponentId) -> bool {
        self.entries.iter().any(|t| t.id == id)
    }

    /// Appends to `out` a presence mask (bit i: the i-th registered component) and the words
    /// of every component `e` has, in registration order.
    fn pack(&self, world: &World, e: Entity, out: &mut Vec<u32>) {
        let at = out.len();
        out.push(0);
        let mut mask = 0u32;
        for (i, t) in self.entries.iter().enumerate() {
            if (t.pack)(world, e, out) {
                mask |= 1 << i;
            }
        }
        out[at] = mask;
    }

    /// The words [`TravellingComponents::pack`] wrote at the start of `w`: how many there are.
    fn extent(&self, w: &[u32]) -> usize {
        let mask = w[0];
        1 + self
            .entries
            .iter()
            .enumerate()
            .filter(|(i, _)| mask & (1 << i) != 0)
            .map(|(_, t)| t.words)
            .sum::<usize>()
    }

    /// Inserts on `e` the components packed in `w` (as [`TravellingComponents::pack`] wrote).
    fn insert(&self, e: &mut EntityWorldMut<'_>, w: &[u32]) {
        let mask = w[0];
        let mut k = 1;
        for (i, t) in self.entries.iter().enumerate() {
            if mask & (1 << i) != 0 {
                (t.insert)(e, &w[k..k + t.words]);
                k += t.words;
            }
        }
    }
}

/// Registers `T` as a travelling particle component of `world` (once; at most 32 are
/// registered). Plugins call it when they add particle state; it costs nothing in a
/// single-process run.
pub fn travel<T: Travels>(world: &mut World) {
    travel_with::<T>(world, T::WORDS, pack_component::<T>, insert_component::<T>);
}

/// Registers `T` as a travelling particle component with packing of its own, for a component
/// that refers to other entities (their `Entity` differs between ranks): `pack` appends
/// `words` words if the particle has a `T` and says whether it did; `insert` rebuilds the `T`
/// on the receiving rank (the entity's world is at hand through `EntityWorldMut::world`).
pub fn travel_with<T: Component>(
    world: &mut World,
    words: usize,
    pack: fn(&World, Entity, &mut Vec<u32>) -> bool,
    insert: fn(&mut EntityWorldMut<'_>, &[u32]),
) {
    let id = world.register_component::<T>();
    let mut reg = world.get_resource_or_init::<TravellingComponents>();
    if reg.contains(id) {
        return;
    }
    assert!(reg.entries.len() < 32, "at most 32 travelling components");
    reg.entries.push(Traveller {
        id,
        words,
        pack,
        insert,
    });
}

/// Appends `values` as words, two per `f64` (low word first), for [`Travels`] impls and
/// messages.
pub fn push_f64s(out: &mut Vec<u32>, values: impl IntoIterator<Item = f64>) {
    for v in values {
        let b = v.to_bits();
        out.extend([b as u32, (b >> 32) as u32]);
    }
}

/// The `k`-th `f64` of words written by [`push_f64s`].
pub fn f64_at(w: &[u32], k: usize) -> f64 {
    f64::from_bits(u64::from(w[2 * k]) | (u64::from(w[2 * k + 1]) << 32))
}

/// Words of `DMat3`s, column-major ([`push_f64s`]).
pub fn push_dmat3s<'a>(out: &mut Vec<u32>, ms: impl IntoIterator<Item = &'a glam::DMat3>) {
    for m in ms {
        push_f64s(out, m.to_cols_array());
    }
}

/// The `k`-th `DMat3` of words written by [`push_dmat3s`].
pub fn dmat3_at(w: &[u32], k: usize) -> glam::DMat3 {
    glam::DMat3::from_cols_array(&std::array::from_fn(|i| f64_at(w, 9 * k + i)))
}

/// Words of a `Mat3`, column-major.
fn pack_mat3(m: &Mat3, out: &mut Vec<u32>) {
    out.extend(m.to_cols_array().map(f32::to_bits));
}

fn unpack_mat3(w: &[u32]) -> Mat3 {
    Mat3::from_cols_array(&std::array::from_fn(|k| f32::from_bits(w[k])))
}

/// A component holding one `Mat3` travels as its 9 entries.
macro_rules! travels_as_mat3 {
    ($($(#[$doc:meta])* $t:ty),*) => {$(
        $(#[$doc])*
        impl Travels for $t {
            const WORDS: usize = 9;
            fn pack(&self, out: &mut Vec<u32>) {
                pack_mat3(&self.0, out);
            }
            fn unpack(w: &[u32]) -> Self {
                Self(unpack_mat3(w))
            }
        }
    )*};
}

travels_as_mat3!(
    DeformationGradient,
    PredictedDeformationGradient,
    /// Per-step scratch, except with a velocity gradient carried from the last G2P
    /// ([`crate::config::VelocityGradientSource::Carried`]): then the next step's stress reads
    /// it, and [`crate::runner::ranks::distribute`] makes it travel.
    VelocityGradient
);

impl Travels for PhaseIndex {
    const WORDS: usize = 1;
    fn pack(&self, out: &mut Vec<u32>) {
        out.push(self.0.to_bits());
    }
    fn unpack(w: &[u32]) -> Self {
        Self(f32::from_bits(w[0]))
    }
}

/// The owner of the particle whose stencil starts at node `base`.
fn owner_of(partition: &Partition, layout: &GridLayout, base: glam::IVec3) -> usize {
    partition.owner(partition.column_of(layout, base))
}

/// Repartitions the columns if the ranks' particle counts drifted apart ([`Ranks::rebalance`]),
/// then sends every particle whose stencil (set by Predict) lies in another rank's columns to
/// that rank, and spawns the particles the others sent here (in rank order, each rank's in its
/// query order). Runs in [`PredictSystems::Migrate`](crate::step::schedule::PredictSystems).
pub fn migrate_particles(world: &mut World) {
    let Some(mut ranks) = world.remove_resource::<Ranks>() else {
        return;
    };
    let layout = world.resource::<MpmGrid>().layout;
    let axis = ranks.partition.axis;
    let rank = ranks.rank();
    let mut per_column = vec![0u64; layout.blocks[axis] as usize];
    // Whether a particle goes further than a neighbour rank (a particle crosses less than a
    // block layer per step, so only after a jump the failure checks will report).
    let mut far = false;
    let mut stencils = world.query_filtered::<&ParticleStencil, With<Particle>>();
    for st in stencils.iter(world) {
        let c = layout.block_of_node(st.base)[axis];
        per_column[c as usize] += 1;
        far |= ranks.partition.owner(c).abs_diff(rank) > 1;
    }
    // One collective: the counts of all ranks, and whether any rank has a far particle.
    let (rebalanced, any_far) = ranks.rebalance_and_flag(&layout, &per_column, far);
    let size = ranks.size();
    let extras = world
        .get_resource::<TravellingComponents>()
        .cloned()
        .unwrap_or_default();
    let mut send = vec![Vec::new(); size];
    let mut leaving = Vec::new();
    let mut q = world.query_filtered::<(Entity, Travelling<'_>), With<Particle>>();
    for (e, p) in q.iter(world) {
        let to = owner_of(&ranks.partition, &layout, p.6.base);
        if to != rank {
            pack_particle(&mut send[to], p);
            extras.pack(world, e, &mut send[to]);
            leaving.push(e);
        }
    }
    for e in &leaving {
        world.despawn(*e);
    }
    ranks.stats.lock().expect("stats lock").migrations += leaving.len() as u64;
    // After a repartition particles may go to any rank; otherwise only to the neighbours.
    let received = if rebalanced || any_far {
        ranks.exchange(send)
    } else {
        let lower = rank.checked_sub(1).map(|r| std::mem::take(&mut send[r]));
        let upper = send.get_mut(rank + 1).map(std::mem::take);
        let (a, b) = ranks
            .timed(|c| c.neighbour_exchange(lower.unwrap_or_default(), upper.unwrap_or_default()));
        vec![a, b]
    };
    // Each record: the fixed words, then the travelling components' mask and words.
    let mut arrived = Vec::new();
    let mut states = Vec::new();
    for m in &received {
        let mut k = 0;
        while k < m.len() {
            arrived.push((Particle, unpack_particle(&m[k..k + PARTICLE_WORDS])));
            k += PARTICLE_WORDS;
            let n = extras.extent(&m[k..]);
            states.push(&m[k..k + n]);
            k += n;
        }
    }
    let spawned: Vec<Entity> = world.spawn_batch(arrived).collect();
    for (e, w) in spawned.into_iter().zip(states) {
        if w[0] != 0 {
            extras.insert(&mut world.entity_mut(e), w);
        }
    }
    world.insert_resource(ranks);
}

/// Despawns the particles this rank does not own (an app that spawned more than its part), by
/// the column of the block their position lies in (the stencil base a zero step predicts).
pub fn keep_own_particles(world: &mut World) {
    let layout = layout_of(world);
    let mut q = world.query_filtered::<(Entity, &Position), With<Particle>>();
    let ranks = world.resource::<Ranks>();
    let gone: Vec<Entity> = q
        .iter(world)
        .filter(|(_, x)| !ranks.owns(&layout, x.0))
        .map(|(e, _)| e)
        .collect();
    for e in gone {
        world.despawn(e);
    }
}

/// The grid layout of `world`'s configuration (the grid resource is made when the run starts).
pub fn layout_of(world: &World) -> GridLayout {
    let c = world.resource::<crate::config::MpmConfig>();
    GridLayout::new(c.domain_min, c.domain_max, c.dx)
}

/// Particles at `positions` per block layer along `axis` (for [`Partition::balanced`]).
pub fn particles_per_column(
    layout: &GridLayout,
    axis: usize,
    positions: impl Iterator<Item = Vec3>,
) -> Vec<u64> {
    let mut counts = vec![0u64; layout.blocks[axis] as usize];
    for x in positions {
        let base = ParticleStencil::at(layout, x).base;
        counts[layout.block_of_node(base)[axis] as usize] += 1;
    }
    counts
}

/// The rank owning a particle at `x` before its first step (the stencil a zero step predicts).
pub fn owner_at(partition: &Partition, layout: &GridLayout, x: Vec3) -> usize {
    owner_of(partition, layout, ParticleStencil::at(layout, x).base)
}

/// The decomposition axis of a domain: the longest of its axes that is not periodic (x on a
/// tie), or `None` if all three are periodic.
pub fn decomposition_axis(extent: Vec3, periodic: [bool; 3]) -> Option<usize> {
    (0..3)
        .filter(|&a| !periodic[a])
        .fold(None, |best: Option<usize>, a| match best {
            Some(b) if extent[b] >= extent[a] => Some(b),
            _ => Some(a),
        })
}

/// Refuses particles that carry components which do not travel with a migration (model state,
/// temperatures, ...), naming the first one found.
pub fn check_particle_components(world: &mut World) -> Result<(), DecompositionError> {
    let allowed: Vec<ComponentId> = [
        world.register_component::<Particle>(),
        world.register_component::<Position>(),
        world.register_component::<Velocity>(),
        world.register_component::<Acceleration>(),
        world.register_component::<Mass>(),
        world.register_component::<Density>(),
        world.register_component::<MaterialId>(),
        world.register_component::<ParticleStencil>(),
        world.register_component::<VelocityGradient>(),
        world.register_component::<PredictedDensity>(),
        world.register_component::<CauchyStress>(),
        world.register_component::<StabilityData>(),
    ]
    .to_vec();
    let travelling = world
        .get_resource::<TravellingComponents>()
        .cloned()
        .unwrap_or_default();
    let particle = allowed[0];
    for archetype in world.archetypes().iter() {
        if archetype.is_empty() || !archetype.contains(particle) {
            continue;
        }
        if let Some(other) = archetype
            .components()
            .iter()
            .copied()
            .find(|c| !allowed.contains(c) && !travelling.contains(*c))
        {
            let name = world
                .components()
                .get_info(other)
                .map_or_else(|| format!("{other:?}"), |i| format!("{}", i.name()));
            return Err(DecompositionError::Unsupported(format!(
                "its particles carry `{name}`, which does not travel between ranks yet (the \
                 plugin that adds it registers it with `treacle::distributed::travel`)"
            )));
        }
    }
    Ok(())
}

/// Every rank's `mine` (a problem, or `None`), gathered by `all_gather` (every rank calls this
/// together): the lowest rank that has one, and its text.
pub fn first_problem(
    mine: Option<&str>,
    all_gather: impl FnOnce(&[u32]) -> Vec<Vec<u32>>,
) -> Option<(usize, String)> {
    // Empty for no problem; otherwise a leading 1 (an empty text is still a problem).
    let msg: Vec<u32> = match mine {
        None => Vec::new(),
        Some(text) => std::iter::once(1)
            .chain(text.bytes().map(u32::from))
            .collect(),
    };
    let all = all_gather(&msg);
    let (r, m) = all.iter().enumerate().find(|(_, m)| !m.is_empty())?;
    let bytes: Vec<u8> = m[1..].iter().map(|&b| b as u8).collect();
    Some((r, String::from_utf8_lossy(&bytes).into_owned()))
}

/// After the monitor: if any rank failed, every rank stops with the lowest failed rank's
/// report (a rank that did not fail names it). Runs in
/// [`MonitorSystems::Agree`](crate::step::schedule::MonitorSystems).
pub fn agree_on_failure(
    ranks: Option<Res<Ranks>>,
    mut status: ResMut<crate::failure::SimulationStatus>,
) {
    let Some(ranks) = ranks else {
        return;
    };
    let mine = status.failure.as_ref().map(|f| f.to_string());
    let first = first_problem(mine.as_deref(), |w| ranks.all_gather_words(w));
    if let (Some((r, text)), None) = (first, &mine) {
        status.failure = Some(crate::failure::FailureReport::global(
            "rank",
            r as f64,
            format!("rank {r} failed: {text}"),
        ));
    }
}
