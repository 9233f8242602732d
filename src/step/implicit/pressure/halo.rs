//! The pressure projection split over ranks (ALGORITHM §12): what the two ranks that share a
//! block column tell each other.
//!
//! A rank's particles lie in the cells of its own columns and in the first cell layer of the
//! column above (a particle's stencil base is in its own columns, and its cell is the base or
//! the next one up), so that layer is the only one two ranks' particles share. Its cells go to
//! the lower rank where it holds all 8 corners (it *claims* them), else to the upper one;
//! every other cell belongs to the rank owning its column. A rank's unknowns are its cells.
//!
//! - Once per step, [`PressureHalo::exchange_cells`]: the shared layer's particle sums both
//!   ways, and the lower rank's claims; [`PressureHalo::exchange_corners`]: each rank's corner
//!   marks on the shared columns, so that both number the same projection nodes there.
//! - Per operator application, [`PressureHalo::sum_nodes`]: a node's Σ ±p over the cells
//!   around it is summed over the two ranks on the shared columns' first two node layers (the
//!   only ones with cells of both ranks around them); a + b = b + a, so both hold the same bits.
//! - After the solve, the same sum over the whole shared column. A node without a pressure of
//!   its own takes the mean correction of its neighbours, some of which only the other rank
//!   may know (below the shared column, or in a shared block only one rank holds). In the band
//!   of the last layer below the shared column and its first three layers both ranks form the
//!   mean from partial sums ([`PressureHalo::band_means`]): each neighbour is counted by one
//!   rank, and the two (sum, count) are added before the division. The shared column's top
//!   layer, whose neighbours above only the upper rank holds, is the upper rank's, copied to
//!   the lower ([`PressureHalo::copy_edge_layers`]).
//! - Before the warm start, [`PressureHalo::hand_over_pressures`]: a cell's last pressure goes
//!   to the rank that may own the cell now (its column's new owner after a repartition; the
//!   neighbour for the shared cell layer, whose claims can change from step to step), so the
//!   solve starts where one process starts. (Without it a cell that changed hands started from
//!   0, and after three repartitions of the projected dam break positions differed from one
//!   process by 1.4e-4 m, ten times the rounding bound: the solver's tolerance, not rounding.)
use glam::{DVec3, IVec3};

use super::{Numbering, bits};
use crate::distributed::{Partition, Ranks, f64_at, push_f64s};
use crate::grid::{BLOCK, BLOCK_NODES, GridLayout, MpmGrid, local_coords};

/// The nodes of a block at local coordinate `l` along `axis`.
pub(super) fn layer(axis: usize, l: i32) -> u64 {
    (0..BLOCK_NODES)
        .filter(|&o| local_coords(o)[axis] == l)
        .fold(0, |m, o| m | 1 << o)
}

fn push_u64(out: &mut Vec<u32>, m: u64) {
    out.extend([m as u32, (m >> 32) as u32]);
}

fn u64_at(w: &[u32], k: usize) -> u64 {
    u64::from(w[k]) | (u64::from(w[k + 1]) << 32)
}

/// The numbers of the nodes of slot `s` marked in `m` (a subset of the numbering's marks).
fn numbered(n: &Numbering, s: usize, m: u64) -> impl Iterator<Item = usize> + '_ {
    let all = n.mask[s];
    let first = n.start[s] as usize;
    bits_of(m).map(move |o| first + (all & ((1u64 << o) - 1)).count_ones() as usize)
}

/// The set bits of `m`, lowest first.
fn bits_of(mut m: u64) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (m != 0).then(|| {
            let o = m.trailing_zeros() as usize;
            m &= m - 1;
            o
        })
    })
}

/// The shared columns of this rank and its neighbours (one step's view of the grid).
pub(super) struct PressureHalo<'a> {
    ranks: &'a Ranks,
    axis: usize,
    /// Per side (0: with rank − 1, this rank's first column; 1: with rank + 1, the column
    /// above its own): the allocated slots of the column and their block keys, in slot order.
    shared: [Vec<(usize, u32)>; 2],
    /// Per side: the neighbour's allocated blocks of the shared column (keys, ascending; from
    /// [`PressureHalo::exchange_corners`]).
    partner: [Vec<u32>; 2],
}

impl<'a> PressureHalo<'a> {
    /// The shared columns of `grid` on `ranks`.
    pub(super) fn new(ranks: &'a Ranks, grid: &MpmGrid) -> Self {
        let (rank, size) = (ranks.rank(), ranks.size());
        let own = ranks.partition.columns(rank);
        let axis = ranks.axis();
        let column = |c: i32| -> Vec<(usize, u32)> {
            let keys = grid.block_keys();
            (0..keys.len())
                .filter(|&s| grid.block_of_key(keys[s])[axis] == c)
                .map(|s| (s, keys[s]))
                .collect()
        };
        let shared = [
            if rank > 0 {
                column(own.start)
            } else {
                Vec::new()
            },
            if rank + 1 < size {
                column(own.end)
            } else {
                Vec::new()
            },
        ];
        Self {
            ranks,
            axis,
            shared,
            partner: [Vec::new(), Vec::new()],
        }
    }

    /// Sends `msg[side]` to the neighbour on that side; returns what arrived from each side.
    fn exchange(&self, [lower, upper]: [Vec<u32>; 2]) -> [Vec<u32>; 2] {
        let (a, b) = self.ranks.neighbour_exchange(lower, upper);
        [a, b]
    }

    /// Completes the cells of the first cell layer of the shared columns (module docs):
    /// `liquid` (this rank's particle cells, per slot) and `cell_volume` (their particle sums)
    /// get the neighbour's particles there; then `liquid` keeps this rank's cells only (in the
    /// column above its own, the cells it claims: all corners allocated, `around` per slot).
    pub(super) fn exchange_cells(
        &self,
        liquid: &mut [u64],
        cell_volume: &mut [(f64, f64)],
        slots: &[([Option<usize>; 27], glam::IVec3)],
        grid: &MpmGrid,
    ) {
        let first = layer(self.axis, 0);
        // To the lower rank: my particle cells of the layer; to the upper: also my claims.
        let claims = |s: usize| !bits::incomplete(&slots[s].0) & first;
        let msg = |side: usize| {
            let mut out = Vec::new();
            for &(s, key) in &self.shared[side] {
                let mine = liquid[s] & first;
                out.push(key);
                push_u64(&mut out, if side == 1 { claims(s) } else { 0 });
                push_u64(&mut out, mine);
                push_f64s(
                    &mut out,
                    bits_of(mine).flat_map(|o| {
                        let v = cell_volume[s * BLOCK_NODES + o];
                        [v.0, v.1]
                    }),
                );
            }
            out
        };
        let received = self.exchange([msg(0), msg(1)]);
        for msg in &received {
            let mut w = &msg[..];
            while !w.is_empty() {
                let (key, their_claims, cells) = (w[0], u64_at(w, 1), u64_at(w, 3));
                let len = 5 + 4 * cells.count_ones() as usize;
                let sums = &w[5..len];
                if let Some(s) = grid.slot_of_block(grid.block_of_key(key)) {
                    for (k, o) in bits_of(cells).enumerate() {
                        let v = &mut cell_volume[s * BLOCK_NODES + o];
                        v.0 += f64_at(sums, 2 * k);
                        v.1 += f64_at(sums, 2 * k + 1);
                    }
                    liquid[s] = (liquid[s] | cells) & !their_claims;
                }
                w = &w[len..];
            }
        }
        for &(s, _) in &self.shared[1] {
            liquid[s] &= claims(s);
        }
    }

    /// Marks in `corners` (per slot) the neighbours' projection nodes on the shared columns,
    /// so that both ranks number the same nodes there.
    pub(super) fn exchange_corners(&mut self, corners: &mut [u64], grid: &MpmGrid) {
        let msg = |side: usize| {
            let mut out = Vec::new();
            for &(s, key) in &self.shared[side] {
                out.push(key);
                push_u64(&mut out, corners[s]);
            }
            out
        };
        let received = self.exchange([msg(0), msg(1)]);
        for (side, msg) in received.iter().enumerate() {
            self.partner[side] = msg.chunks_exact(3).map(|w| w[0]).collect();
            for w in msg.chunks_exact(3) {
                if let Some(s) = grid.slot_of_block(grid.block_of_key(w[0])) {
                    corners[s] |= u64_at(w, 1);
                }
            }
        }
    }

    /// The neighbour means of the band around each shared column (module docs): for the nodes
    /// of this rank in the last layer below the shared column and in its first three layers,
    /// the mean of `correction(n)` over the neighbours that are projection nodes (`n`: their
    /// number in `corners`; `None` for one that does not count, a node without mass), as
    /// both ranks form it: each neighbour is counted by one rank (below the shared column the
    /// lower, above it the upper, in it the upper where it holds the block and else the
    /// lower), and the two ranks' partial sums and counts are added before the division.
    /// Returns per slot the mask of its band nodes, and the means by grid index (a band node
    /// without a counted neighbour has none).
    pub(super) fn band_means(
        &self,
        grid: &MpmGrid,
        corners: &Numbering,
        correction: impl Fn(usize) -> Option<DVec3>,
    ) -> (Vec<u64>, std::collections::HashMap<usize, DVec3>) {
        use std::collections::btree_map::Entry;
        use std::collections::{BTreeMap, HashMap};
        let layout = grid.layout;
        let p = &self.ranks.partition;
        let (rank, size) = (self.ranks.rank(), self.ranks.size());
        let own = p.columns(rank);
        let place = |c: IVec3| {
            (
                p.column_of(&layout, c),
                (c - layout.lo)[self.axis].rem_euclid(BLOCK),
            )
        };
        let inside = |c: IVec3| {
            let r = c - layout.lo;
            r.min_element() >= 0 && (r - layout.dims).max_element() < 0
        };
        let mut masks = vec![0u64; grid.block_count()];
        let mut sends = [Vec::new(), Vec::new()];
        let mut partials: [BTreeMap<usize, (DVec3, u32)>; 2] = Default::default();
        for side in 0..2 {
            if (side == 0 && rank == 0) || (side == 1 && rank + 1 == size) {
                continue;
            }
            // The shared column, and whether this rank is the upper one there.
            let (s, upper) = if side == 0 {
                (own.start, true)
            } else {
                (own.end, false)
            };
            let in_band = |c: IVec3| {
                let (col, l) = place(c);
                (col == s - 1 && l == BLOCK - 1) || (col == s && l < BLOCK - 1)
            };
            let partner = &self.partner[side];
            let counted = |col: i32, key: u32| {
                if upper {
                    col >= s
                } else {
                    col < s || (col == s && partner.binary_search(&key).is_err())
                }
            };
            let partial = &mut partials[side];
            let keys = grid.block_keys();
            for slot in 0..keys.len() {
                let col = grid.block_of_key(keys[slot])[self.axis];
                if col != s - 1 && col != s {
                    continue;
                }
                let origin = grid.slot_origin(slot);
                for o in 0..BLOCK_NODES {
                    if in_band(origin + local_coords(o)) {
                        masks[slot] |= 1 << o;
                    }
                }
                if !counted(col, keys[slot]) {
                    continue;
                }
                for (o, n) in
                    bits_of(corners.mask[slot]).zip(numbered(corners, slot, corners.mask[slot]))
                {
                    let Some(g) = correction(n) else { continue };
                    let j = origin + local_coords(o);
                    for d in super::NEIGHBOURS {
                        let i = j + d;
                        if inside(i) && in_band(i) {
                            let e = partial.entry(layout.index(i)).or_insert((DVec3::ZERO, 0));
                            e.0 += g;
                            e.1 += 1;
                        }
                    }
                }
            }
            for (&key, &(sum, count)) in partial.iter() {
                push_u64(&mut sends[side], key as u64);
                push_f64s(&mut sends[side], sum.to_array());
                sends[side].push(count);
            }
        }
        let received = self.exchange(sends);
        let mut means = HashMap::new();
        for (totals, msg) in partials.iter_mut().zip(&received) {
            for w in msg.chunks_exact(9) {
                let v = |k| f64_at(&w[2..], k);
                let (sum, count) = (DVec3::new(v(0), v(1), v(2)), w[8]);
                // a + b on one rank, b + a on the other: the same bits.
                match totals.entry(u64_at(w, 0) as usize) {
                    Entry::Occupied(mut e) => {
                        let e = e.get_mut();
                        e.0 += sum;
                        e.1 += count;
                    }
                    Entry::Vacant(e) => {
                        e.insert((sum, count));
                    }
                }
            }
            for (&key, &(sum, count)) in totals.iter() {
                if let Some(i) = grid.index(layout.node_of_index(key)) {
                    means.insert(i, sum / f64::from(count));
                }
            }
        }
        (masks, means)
    }

    /// Adds to `v` (per projection node of `corners`) the neighbours' values on the nodes of
    /// the shared columns at the local layers `layers` along the axis (a mask of 0..4).
    pub(super) fn sum_nodes(&self, corners: &Numbering, v: &mut [DVec3], layers: u8) {
        let mask = (0..BLOCK)
            .filter(|l| layers >> l & 1 != 0)
            .fold(0, |m, l| m | layer(self.axis, l));
        let msg = |side: usize| {
            let mut out = Vec::new();
            for &(s, key) in &self.shared[side] {
                let m = corners.mask[s] & mask;
                out.push(key);
                push_u64(&mut out, m);
                push_f64s(
                    &mut out,
                    numbered(corners, s, m).flat_map(|n| v[n].to_array()),
                );
            }
            out
        };
        let received = self.exchange([msg(0), msg(1)]);
        for (side, msg) in received.iter().enumerate() {
            // Both ranks list the column's blocks in ascending key order.
            let mut mine = self.shared[side].iter().peekable();
            let mut w = &msg[..];
            while !w.is_empty() {
                let (key, m) = (w[0], u64_at(w, 1));
                let len = 3 + 6 * m.count_ones() as usize;
                let values = &w[3..len];
                while mine.next_if(|e| e.1 < key).is_some() {}
                if let Some(&&(s, _)) = mine.peek().filter(|e| e.1 == key) {
                    let (all, first) = (corners.mask[s], corners.start[s] as usize);
                    for (k, o) in bits_of(m).enumerate() {
                        if all >> o & 1 != 0 {
                            let n = first + (all & ((1u64 << o) - 1)).count_ones() as usize;
                            v[n] += DVec3::new(
                                f64_at(values, 3 * k),
                                f64_at(values, 3 * k + 1),
                                f64_at(values, 3 * k + 2),
                            );
                        }
                    }
                }
                w = &w[len..];
            }
        }
    }

    /// Overwrites the lower rank's top node layer of each shared column with the upper rank's
    /// new velocities and accelerations (module docs).
    pub(super) fn copy_edge_layers(&self, grid: &mut MpmGrid) {
        // Of a shared column the upper rank sends the lower its layer 3 (side 0 of the upper
        // rank); the other layers are the band's, which both ranks form alike.
        let sent = [layer(self.axis, BLOCK - 1), 0];
        let msg = |side: usize| {
            let mut out = Vec::new();
            if sent[side] == 0 {
                return out;
            }
            for &(s, key) in &self.shared[side] {
                out.push(key);
                for o in bits_of(sent[side]) {
                    let n = &grid.nodes[s * BLOCK_NODES + o];
                    out.extend(n.new_velocity.to_array().map(f32::to_bits));
                    out.extend(n.new_acceleration.to_array().map(f32::to_bits));
                }
            }
            out
        };
        let received = self.exchange([msg(0), msg(1)]);
        let per_block = 1 + 6 * (BLOCK * BLOCK) as usize;
        for (side, msg) in received.iter().enumerate() {
            // From the upper rank its layer 3 of the column above mine.
            let took = sent[1 - side];
            for w in msg.chunks_exact(per_block) {
                let Some(s) = grid.slot_of_block(grid.block_of_key(w[0])) else {
                    continue;
                };
                let f = |k: usize| f32::from_bits(w[1 + k]);
                for (k, o) in bits_of(took).enumerate() {
                    let n = &mut grid.nodes[s * BLOCK_NODES + o];
                    n.new_velocity = glam::Vec3A::new(f(6 * k), f(6 * k + 1), f(6 * k + 2));
                    n.new_acceleration = glam::Vec3A::new(f(6 * k + 3), f(6 * k + 4), f(6 * k + 5));
                }
            }
        }
    }

    /// Hands the last step's cell pressures (`previous`: (dense cell key, pressure) of this
    /// rank's cells, sorted by key) to the ranks that may own the cells now (module docs):
    /// after a repartition (`last`: the partition of the last step) every entry to the owner of
    /// its column (all ranks at once), and every step the entries of the shared columns' first
    /// cell layer to the neighbour. Afterwards `previous` holds every last pressure of a cell
    /// this rank may own now, sorted by key.
    pub(super) fn hand_over_pressures(
        &self,
        previous: &mut Vec<(usize, f64)>,
        last: &mut Option<Partition>,
        layout: &GridLayout,
    ) {
        let p = &self.ranks.partition;
        let (rank, size) = (self.ranks.rank(), self.ranks.size());
        // A cell's column, and whether it is in the column's first cell layer.
        let place = |key: usize| {
            let c = layout.node_of_index(key);
            (
                p.column_of(layout, c),
                (c - layout.lo)[self.axis].rem_euclid(BLOCK) == 0,
            )
        };
        let push = |out: &mut Vec<u32>, &(key, value): &(usize, f64)| {
            push_u64(out, key as u64);
            push_f64s(out, [value]);
        };
        let take = |previous: &mut Vec<(usize, f64)>, msg: &[u32]| {
            previous.extend(
                msg.chunks_exact(4)
                    .map(|w| (u64_at(w, 0) as usize, f64_at(&w[2..], 0))),
            );
        };
        if last.as_ref().is_some_and(|l| l != p) {
            let mut send = vec![Vec::new(); size];
            previous.retain(|e| {
                let to = p.owner(place(e.0).0);
                if to != rank {
                    push(&mut send[to], e);
                }
                to == rank
            });
            for msg in self.ranks.exchange(send) {
                take(previous, &msg);
            }
        }
        *last = Some(p.clone());
        let own = p.columns(rank);
        let mut send = [Vec::new(), Vec::new()];
        for e in previous.iter() {
            let (column, first) = place(e.0);
            if first && column == own.start && rank > 0 {
                push(&mut send[0], e);
            }
            if first && column == own.end && rank + 1 < size {
                push(&mut send[1], e);
            }
        }
        for msg in self.exchange(send) {
            take(previous, &msg);
        }
        previous.sort_unstable_by_key(|e| e.0);
        // A cell handed over both ways (a repartition, then the shared layer) arrives twice,
        // with the same value.
        previous.dedup_by_key(|e| e.0);
    }
}
