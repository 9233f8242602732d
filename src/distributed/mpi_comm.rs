//! [`MpiComm`]: the [`Transport`] of a process started by `mpirun` (feature `mpi`, rsmpi).
use mpi::datatype::{Partition, PartitionMut};
use mpi::environment::Universe;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use mpi::{Count, Threading};

use super::Communicator as Transport;

/// MPI's world communicator. Dropping it finalizes MPI.
pub struct MpiComm {
    world: SimpleCommunicator,
    // This rank and the rank count, asked once: the distributed systems ask for them per node
    // and per particle, and each MPI query is a library call (3–4 % of a heat step on 2 ranks
    // before they were cached).
    rank: usize,
    size: usize,
    // Dropped after `world` (field order): finalizes MPI.
    _universe: Universe,
}

// SAFETY: MPI is initialised with `Threading::Serialized` (or better): calls may come from any
// thread as long as no two run at once. Every call goes through `&self` methods that the
// distributed systems make one after another (Bevy's step schedule runs its systems one at a
// time, and the runner calls between schedule runs), never from two threads at once.
unsafe impl Send for MpiComm {}
// SAFETY: as above.
unsafe impl Sync for MpiComm {}

impl MpiComm {
    /// Initialises MPI; `None` if it was initialised before or the library cannot serialise
    /// calls from several threads.
    pub fn init() -> Option<Self> {
        let (universe, threading) = mpi::initialize_with_threading(Threading::Serialized)?;
        if threading < Threading::Serialized {
            return None;
        }
        let world = universe.world();
        Some(Self {
            rank: world.rank() as usize,
            size: world.size() as usize,
            world,
            _universe: universe,
        })
    }

    /// Ends every rank of the job with exit code `code` (a rank that cannot go on alone).
    pub fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }
}

fn displacements(counts: &[Count]) -> Vec<Count> {
    counts
        .iter()
        .scan(0, |acc, &c| {
            let d = *acc;
            *acc += c;
            Some(d)
        })
        .collect()
}

impl Transport for MpiComm {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn exchange(&self, send: Vec<Vec<u32>>) -> Vec<Vec<u32>> {
        let size = self.size();
        assert_eq!(send.len(), size, "one message per rank");
        let send_counts: Vec<Count> = send
            .iter()
            .map(|m| Count::try_from(m.len()).expect("a message of fewer than 2^31 words"))
            .collect();
        let mut recv_counts = vec![0 as Count; size];
        self.world
            .all_to_all_into(&send_counts[..], &mut recv_counts[..]);
        let flat: Vec<u32> = send.concat();
        let total: usize = recv_counts.iter().map(|&c| c as usize).sum();
        let mut recv = vec![0u32; total];
        let (sd, rd) = (displacements(&send_counts), displacements(&recv_counts));
        {
            let sp = Partition::new(&flat[..], &send_counts[..], &sd[..]);
            let mut rp = PartitionMut::new(&mut recv[..], &recv_counts[..], &rd[..]);
            self.world.all_to_all_varcount_into(&sp, &mut rp);
        }
        (0..size)
            .map(|r| recv[rd[r] as usize..(rd[r] + recv_counts[r]) as usize].to_vec())
            .collect()
    }

    fn all_gather(&self, words: &[u32]) -> Vec<Vec<u32>> {
        let size = self.size();
        let count = Count::try_from(words.len()).expect("a message of fewer than 2^31 words");
        let mut counts = vec![0 as Count; size];
        self.world.all_gather_into(&count, &mut counts[..]);
        let displs = displacements(&counts);
        let mut recv = vec![0u32; counts.iter().map(|&c| c as usize).sum()];
        {
            let mut rp = PartitionMut::new(&mut recv[..], &counts[..], &displs[..]);
            self.world.all_gather_varcount_into(words, &mut rp);
        }
        (0..size)
            .map(|r| recv[displs[r] as usize..(displs[r] + counts[r]) as usize].to_vec())
            .collect()
    }

    fn neighbour_exchange(&self, lower: Vec<u32>, upper: Vec<u32>) -> (Vec<u32>, Vec<u32>) {
        let (rank, size) = (self.world.rank(), self.world.size());
        // Tags: 1 for a message to the rank above, 2 to the rank below.
        mpi::request::scope(|scope| {
            let below = (rank > 0).then(|| {
                self.world
                    .process_at_rank(rank - 1)
                    .immediate_send_with_tag(scope, &lower[..], 2)
            });
            let above = (rank + 1 < size).then(|| {
                self.world
                    .process_at_rank(rank + 1)
                    .immediate_send_with_tag(scope, &upper[..], 1)
            });
            let from_lower = if rank > 0 {
                self.world
                    .process_at_rank(rank - 1)
                    .receive_vec_with_tag::<u32>(1)
                    .0
            } else {
                Vec::new()
            };
            let from_upper = if rank + 1 < size {
                self.world
                    .process_at_rank(rank + 1)
                    .receive_vec_with_tag::<u32>(2)
                    .0
            } else {
                Vec::new()
            };
            for request in [below, above].into_iter().flatten() {
                request.wait();
            }
            (from_lower, from_upper)
        })
    }
}
