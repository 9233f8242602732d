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
        Some(Self {
            world: universe.world(),
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
        self.world.rank() as usize
    }

    fn size(&self) -> usize {
        self.world.size() as usize
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
}
