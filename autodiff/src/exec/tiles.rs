//! Running a region: its cut into tiles and chunks, the chunks on rayon's
//! threads, and the reductions after them.
//!
//! Each tile runs the region's instructions in order (forward) and their
//! vector-Jacobian products in reverse (backward), calling the ops' own tile
//! kernels (`kernels::map`, `sum`, `gather`, `scatter_add`) on
//! slices that this file resolves: tile slots, tile ranges of full-length
//! buffers, broadcast scalars, and the accumulators that chunk 0 shares
//! with the real buffers and the other chunks keep private.

use std::ops::Range;

use rayon::prelude::*;

use super::plan::{GatherGroup, Instr, Out, Region, Src};
use super::{Executor, first_non_finite};
use super::{Graph, NONE, Node, NonFinite, Op};
use crate::kernels::{add_into, gather, scatter_add, sum};
use crate::real::Real;

/// Most elements per tile.
const TILE: usize = 1024;

/// Fewest elements per tile: below this the per-op dispatch dominates.
const MIN_TILE: usize = 256;

/// Bytes of tile values and adjoints a chunk aims to keep in the per-core L2
/// cache: a long chain (a renderer's few hundred ops per sample) gets
/// shorter tiles than a short one.
const TILE_BYTES: usize = 512 << 10;

/// The tile length of a region with `slots` tile arrays: the longest power
/// of two whose values and adjoints fit [`TILE_BYTES`], within
/// [`MIN_TILE`]..=[`TILE`]. Depends on the program only, never on threads.
fn tile_for<T>(slots: usize) -> usize {
    let fit = TILE_BYTES / (2 * std::mem::size_of::<T>() * slots.max(1));
    let pow2 = if fit == 0 { 1 } else { 1 << fit.ilog2() };
    pow2.clamp(MIN_TILE, TILE)
}

/// Regions below this length run on the calling thread.
const PARALLEL_MIN_LEN: usize = 1 << 15;

/// Longer regions are cut into this many chunks of tiles, spread over the
/// threads: enough for this project's 2-4 core machines, and few enough that
/// the private accumulation buffers of the extra chunks stay cheap.
const CHUNKS: usize = 4;

/// Which pass a region runs.
#[derive(Clone, Copy, Debug)]
pub(super) enum Pass {
    /// Values (and, with `sinks`, the sums and scatter-adds).
    Forward { sinks: bool },
    /// Recompute the tile values, then the vector-Jacobian products.
    Backward,
    /// Forward with sinks, then backward, tile by tile.
    Fused,
}

impl Pass {
    fn forward_sinks(self) -> bool {
        matches!(self, Pass::Forward { sinks: true } | Pass::Fused)
    }
    fn backward(self) -> bool {
        matches!(self, Pass::Backward | Pass::Fused)
    }
}

/// How a region's run is cut: tiles of `tile_len` elements, in `threads`
/// contiguous chunks of tiles.
struct Cut {
    tile_len: usize,
    tiles: usize,
    threads: usize,
}

impl Cut {
    /// The cut of `reg`: its tile length from its slots, its chunks from its
    /// length.
    fn new<T>(reg: &Region) -> Cut {
        let tile = tile_for::<T>(reg.slots + reg.bcasts.len());
        let tiles = reg.len.div_ceil(tile);
        // The split depends on the length only, never on the thread count, so
        // that accumulations (scatter outputs, gradients of gathered arrays and
        // broadcast scalars) add up in the same order on any machine.
        let threads = if reg.len >= PARALLEL_MIN_LEN {
            CHUNKS.min(tiles)
        } else {
            1
        };
        Cut {
            tile_len: reg.len.min(tile),
            tiles,
            threads,
        }
    }

    /// The tiles of chunk `c`.
    fn chunk(&self, c: usize) -> Range<usize> {
        self.tiles * c / self.threads..self.tiles * (c + 1) / self.threads
    }
}

impl<T: Real> Graph<T> {
    /// Runs region `r` forward (optionally without its sinks) or backward.
    pub(super) fn run_region(&mut self, r: usize, pass: Pass) {
        let reg = self.exec.regions[r].clone();
        if pass.backward() {
            self.prepare_gradients(&reg);
        }
        self.bind_buffers(&reg);
        let cut = Cut::new::<T>(&reg);
        self.exec.prepare_chunks(&reg, pass, &cut);
        self.exec
            .prepare_outputs(&reg, pass, cut.tiles, &self.nodes, &self.edges);
        self.run_chunks(&reg, pass, &cut);
        self.exec.reduce_chunks(&reg, pass, cut.threads);
        if pass.backward() {
            self.add_broadcast_gradients(&reg, cut.threads);
        }
        for &i in &self.exec.arrays[reg.arrays.clone()] {
            self.nodes[i as usize].fresh = false;
        }
        if pass.forward_sinks() {
            self.exec.finish_sums(&reg, cut.tiles);
        }
        if self.check_finite && self.non_finite.is_none() {
            self.non_finite = self.exec.found_non_finite(&reg, pass, cut.threads);
        }
    }

    /// Gives the region's arrays that need a gradient (kept values and
    /// external arrays) and its broadcast scalars their gradient buffers
    /// before the chunks start.
    fn prepare_gradients(&mut self, reg: &Region) {
        for a in reg.arrays.clone() {
            let i = self.exec.arrays[a];
            let gathered = self.exec.shared[reg.shared.clone()].contains(&((a - reg.arrays.start) as u32, false));
            if !self.exec.live[i as usize] || self.nodes[i as usize].adjoint != NONE {
                continue;
            }
            if gathered {
                self.adjoint_of(i);
            } else {
                // Nothing was added yet: the region's first contribution
                // per element writes instead of adding (no zeroing pass).
                let len = self.nodes[i as usize].len as usize;
                self.nodes[i as usize].adjoint = self.adjoints.take(len);
                self.nodes[i as usize].fresh = true;
            }
        }
        for b in reg.bcasts.clone() {
            let i = self.exec.bcasts[b];
            if self.exec.live[i as usize] {
                self.adjoint_of(i);
            }
        }
    }

    /// Points the executor's array table at the region's value and gradient
    /// buffers, and reads its broadcast scalars.
    fn bind_buffers(&mut self, reg: &Region) {
        let ex = &mut self.exec;
        ex.vals.clear();
        ex.adjs.clear();
        for a in reg.arrays.clone() {
            let n = &self.nodes[ex.arrays[a] as usize];
            ex.vals
                .push(Ptr::of(&mut self.values.bufs[n.value as usize][..n.len as usize]));
            ex.adjs.push(if n.adjoint == NONE {
                Ptr::NULL
            } else {
                Ptr::of(&mut self.adjoints.bufs[n.adjoint as usize][..n.len as usize])
            });
        }
        ex.bcast_values.clear();
        for b in reg.bcasts.clone() {
            let n = &self.nodes[ex.bcasts[b] as usize];
            ex.bcast_values.push(self.values.bufs[n.value as usize][0]);
        }
    }

    /// Runs the region's chunks of tiles: on rayon's threads, or one after
    /// the other when there is one chunk or one thread.
    fn run_chunks(&mut self, reg: &Region, pass: Pass, cut: &Cut) {
        let ex = &mut self.exec;
        let ctx = Ctx {
            nodes: &self.nodes,
            edges: &self.edges,
            instrs: &ex.instrs[reg.instrs.clone()],
            group_members: &ex.group_members[reg.group_members.clone()],
            shared: &ex.shared[reg.shared.clone()],
            vals: &ex.vals,
            adjs: &ex.adjs,
            bcast_values: &ex.bcast_values,
            live: &ex.live,
            overwrite: &ex.overwrite,
            bcast_nodes: &ex.bcasts[reg.bcasts.clone()],
            partials: Ptr::of(&mut ex.partials),
            len: reg.len,
            tile_len: cut.tile_len,
            slots: reg.slots,
            sums: reg.sums,
            check_finite: self.check_finite,
            pass,
        };
        let chunks = &mut ex.chunks[..cut.threads];
        if cut.threads == 1 || rayon::current_num_threads() == 1 {
            for (c, chunk) in chunks.iter_mut().enumerate() {
                ctx.run_chunk(chunk, c, cut.chunk(c));
            }
        } else {
            chunks.par_iter_mut().enumerate().for_each(|(c, chunk)| {
                ctx.run_chunk(chunk, c, cut.chunk(c));
            });
        }
    }

    /// Adds each chunk's sum of the broadcast scalars' tile gradients, in
    /// chunk order, into the scalars' gradients.
    fn add_broadcast_gradients(&mut self, reg: &Region, threads: usize) {
        let ex = &self.exec;
        for (b, k) in reg.bcasts.clone().enumerate() {
            let i = ex.bcasts[k] as usize;
            if ex.live[i] {
                let total = ex.chunks[..threads]
                    .iter()
                    .fold(T::zero(), |acc, c| acc + c.bcast_grads[b]);
                let a = self.nodes[i].adjoint as usize;
                self.adjoints.bufs[a][0] += total;
            }
        }
    }
}

impl<T: Real> Executor<T> {
    /// Sizes each chunk's tile slots and broadcast-gradient sums for the
    /// region's run, and its private accumulators: chunk 0 accumulates
    /// straight into the real buffers, the others into private zeroed copies.
    fn prepare_chunks(&mut self, reg: &Region, pass: Pass, cut: &Cut) {
        let per_chunk = (reg.slots + reg.bcasts.len()) * cut.tile_len;
        if self.chunks.len() < cut.threads {
            self.chunks.resize_with(cut.threads, Chunk::default);
        }
        for (c, chunk) in self.chunks[..cut.threads].iter_mut().enumerate() {
            chunk.vals.resize(per_chunk, T::zero());
            if pass.backward() {
                chunk.adjs.resize(per_chunk, T::zero());
                chunk.bcast_grads.clear();
                chunk.bcast_grads.resize(reg.bcasts.len(), T::zero());
            }
            chunk.non_finite = None;
            if chunk.privates.len() < reg.shared.len() {
                chunk.privates.resize_with(reg.shared.len(), Vec::new);
            }
            for (s, p) in chunk.privates[..reg.shared.len()].iter_mut().enumerate() {
                let (target, scatter) = self.shared[reg.shared.start + s];
                let needed = if scatter {
                    pass.forward_sinks()
                } else {
                    pass.backward() && self.live[self.arrays[reg.arrays.start + target as usize] as usize]
                };
                let len = if c == 0 || !needed {
                    0
                } else {
                    self.vals[target as usize].len
                };
                p.clear();
                p.resize(len, T::zero());
            }
        }
    }

    /// Zeroes what the chunks accumulate into before they start (scatter
    /// outputs, sums' tile partials, and in a backward pass the fresh
    /// gradient buffers it does not write), and marks which backward
    /// contributions overwrite instead of adding.
    fn prepare_outputs(&mut self, reg: &Region, pass: Pass, tiles: usize, nodes: &[Node<T>], edges: &[u32]) {
        if pass.forward_sinks() {
            // Scatter outputs start at zero (chunk 0 writes into them).
            for ins in &self.instrs[reg.instrs.clone()] {
                if let Out::Scatter(_, a) = ins.out {
                    // SAFETY: no chunk runs yet.
                    unsafe { self.vals[a as usize].slice(0, self.vals[a as usize].len) }.fill(T::zero());
                }
            }
        }
        self.partials.clear();
        self.partials.resize(tiles * reg.sums, 0.0);
        if pass.backward() {
            self.overwrite_flags(nodes, edges, reg);
            // A fresh gradient buffer that this pass does not write is zero.
            for (a, &i) in self.arrays[reg.arrays.clone()].iter().enumerate() {
                if nodes[i as usize].fresh && !self.touched[reg.slots + reg.bcasts.len() + a] {
                    // SAFETY: no chunk runs yet.
                    unsafe { self.adjs[a].slice(0, self.adjs[a].len) }.fill(T::zero());
                }
            }
        }
    }

    /// Adds the private accumulators of chunks 1.. into the real buffers,
    /// in chunk order.
    fn reduce_chunks(&mut self, reg: &Region, pass: Pass, threads: usize) {
        for (s, &(target, scatter)) in self.shared[reg.shared.clone()].iter().enumerate() {
            // A scatter-add's privates hold values (its forward), the rest
            // gradients (the backward): a fused pass reduces both.
            let (dst, wanted) = match scatter {
                true => (self.vals[target as usize], pass.forward_sinks()),
                false => (self.adjs[target as usize], pass.backward()),
            };
            if dst.ptr.is_null() || !wanted {
                continue;
            }
            // SAFETY: the chunks are done; `dst` is the only reference.
            let dst = unsafe { dst.slice(0, dst.len) };
            for chunk in &self.chunks[1..threads] {
                if !chunk.privates[s].is_empty() {
                    add_into(dst, &chunk.privates[s]);
                }
            }
        }
    }

    /// Writes each sum of the region from its tiles' partials.
    fn finish_sums(&mut self, reg: &Region, tiles: usize) {
        let mut k = 0;
        for ins in &self.instrs[reg.instrs.clone()] {
            if let Out::Sum(p, a) = ins.out {
                // SAFETY: the chunks are done.
                let v = unsafe { self.vals[a as usize].slice(0, 1) };
                v[0] = sum::finish((0..tiles).map(|t| self.partials[t * reg.sums + p as usize]));
                k += 1;
            }
        }
        debug_assert_eq!(k, reg.sums);
    }

    /// The first non-finite value of the region's run (lowest node, then
    /// lowest element), the sums' values included.
    fn found_non_finite(&self, reg: &Region, pass: Pass, threads: usize) -> Option<NonFinite> {
        let found = self.chunks[..threads]
            .iter()
            .filter_map(|c| c.non_finite.clone())
            .min_by_key(|nf| (nf.node, nf.index));
        if found.is_some() || !pass.forward_sinks() {
            return found;
        }
        self.instrs[reg.instrs.clone()].iter().find_map(|ins| {
            let Out::Sum(_, a) = ins.out else { return None };
            // SAFETY: the chunks are done.
            let v = unsafe { self.vals[a as usize].slice(0, 1) };
            first_non_finite(v, ins.node, "sum", 0, false)
        })
    }

    /// Bytes reserved by the scratch buffers.
    pub(crate) fn reserved_bytes(&self) -> usize {
        let t = std::mem::size_of::<T>();
        self.chunks
            .iter()
            .map(|c| {
                (c.vals.capacity() + c.adjs.capacity() + c.bcast_grads.capacity()) * t
                    + c.privates.iter().map(|p| p.capacity() * t).sum::<usize>()
            })
            .sum::<usize>()
            + self.partials.capacity() * 8
    }
}

/// Per-chunk scratch: tile slots for values and adjoints, private
/// accumulation buffers, broadcast-gradient sums, the first non-finite value.
#[derive(Default)]
pub(super) struct Chunk<T> {
    vals: Vec<T>,
    adjs: Vec<T>,
    privates: Vec<Vec<T>>,
    /// Views of `privates` for the tiles (kept to reuse the allocation).
    private_ptrs: Vec<Ptr<T>>,
    bcast_grads: Vec<T>,
    non_finite: Option<NonFinite>,
}

/// What the chunks of one region run share (read-only, or written through
/// `Ptr`s at disjoint places).
struct Ctx<'a, T: Real> {
    nodes: &'a [Node<T>],
    edges: &'a [u32],
    instrs: &'a [Instr],
    /// The region's gather groups ([`Instr::groups`] index them).
    group_members: &'a [u32],
    shared: &'a [(u32, bool)],
    vals: &'a [Ptr<T>],
    adjs: &'a [Ptr<T>],
    bcast_values: &'a [T],
    live: &'a [bool],
    /// Per instruction, bit k: input k's contribution is the first to its
    /// tile slot, so it overwrites (no zeroing of adjoint slots).
    overwrite: &'a [u8],
    bcast_nodes: &'a [u32],
    partials: Ptr<f64>,
    len: usize,
    tile_len: usize,
    slots: usize,
    sums: usize,
    check_finite: bool,
    pass: Pass,
}

impl<T: Real> Ctx<'_, T> {
    /// Runs the tiles `tiles` of chunk `c` with the chunk's scratch.
    fn run_chunk(&self, chunk: &mut Chunk<T>, c: usize, tiles: Range<usize>) {
        let tl = self.tile_len;
        for (b, &v) in self.bcast_values.iter().enumerate() {
            chunk.vals[(self.slots + b) * tl..(self.slots + b + 1) * tl].fill(v);
        }
        let vals = Ptr::of(&mut chunk.vals);
        let adjs = Ptr::of(&mut chunk.adjs);
        chunk.private_ptrs.clear();
        chunk.private_ptrs.extend(chunk.privates.iter_mut().map(|v| Ptr::of(v)));
        let privates = &chunk.private_ptrs[..];
        for t in tiles {
            let t0 = t * self.tile_len;
            let n = self.tile_len.min(self.len - t0);
            let tile = Tile {
                t0,
                n,
                vals,
                adjs,
                privates,
                chunk: c,
            };
            match self.pass {
                Pass::Forward { sinks } => {
                    self.forward_tile(&tile, sinks, false, &mut chunk.non_finite, t);
                }
                Pass::Backward => {
                    self.forward_tile(&tile, false, true, &mut chunk.non_finite, t);
                    self.backward_tile(&tile, &mut chunk.bcast_grads, &mut chunk.non_finite);
                }
                Pass::Fused => {
                    self.forward_tile(&tile, true, false, &mut chunk.non_finite, t);
                    self.backward_tile(&tile, &mut chunk.bcast_grads, &mut chunk.non_finite);
                }
            }
        }
    }

    /// Value of source `s` over the tile.
    #[inline(always)]
    fn value<'b>(&self, tile: &Tile<'_, T>, s: Src) -> &'b [T] {
        // SAFETY: slots and broadcasts belong to this chunk; array reads cover
        // the tile's own range, written only by this chunk (or before the run).
        unsafe {
            match s {
                Src::Slot(k) => tile.vals.slice(k as usize * self.tile_len, tile.n),
                Src::Array(a) => self.vals[a as usize].slice(tile.t0, tile.n),
                Src::Bcast(b) => tile.vals.slice((self.slots + b as usize) * self.tile_len, tile.n),
            }
        }
    }

    /// Adjoint of source `s` over the tile (None when no gradient flows there).
    #[inline(always)]
    fn adjoint<'b>(&self, tile: &Tile<'_, T>, s: Src) -> Option<&'b mut [T]> {
        // SAFETY: as for `value`; adjoint buffers of arrays exist when live.
        unsafe {
            match s {
                Src::Slot(k) => Some(tile.adjs.slice(k as usize * self.tile_len, tile.n)),
                Src::Array(a) => {
                    let p = self.adjs[a as usize];
                    (!p.ptr.is_null()).then(|| p.slice(tile.t0, tile.n))
                }
                Src::Bcast(b) => Some(tile.adjs.slice((self.slots + b as usize) * self.tile_len, tile.n)),
            }
        }
    }

    /// Where an op's output is read from, by the later ops of the tile.
    fn out_src(out: Out) -> Src {
        match out {
            Out::Slot(k) => Src::Slot(k),
            Out::Array(a) | Out::Sum(_, a) | Out::Scatter(_, a) => Src::Array(a),
        }
    }

    /// Forward over one tile. `recompute`: only the values that live in
    /// slots (the others are in buffers already), and no sinks.
    fn forward_tile(&self, tile: &Tile<'_, T>, sinks: bool, recompute: bool, nf: &mut Option<NonFinite>, t: usize) {
        for ins in self.instrs {
            let node = &self.nodes[ins.node as usize];
            let slot_out = matches!(ins.out, Out::Slot(_));
            match node.op {
                Op::Map(kind, p) => {
                    if recompute && !slot_out {
                        continue;
                    }
                    let x = [
                        self.value(tile, ins.ins[0]),
                        self.value(tile, ins.ins[1]),
                        self.value(tile, ins.ins[2]),
                    ];
                    let y = self.out_mut(tile, ins.out);
                    kind.forward(x, y, p);
                    if self.check_finite && nf.is_none() {
                        *nf = first_non_finite(y, ins.node, kind.name(), tile.t0, false);
                    }
                }
                Op::Gather { .. } => {
                    let group = ins.groups[recompute as usize];
                    if group.len > 0 {
                        self.gather_group(tile, group, nf);
                    }
                }
                Op::Sum if sinks => {
                    let Out::Sum(k, _) = ins.out else { unreachable!() };
                    let x = self.value(tile, ins.ins[0]);
                    // SAFETY: each tile owns its partials.
                    let partial = unsafe { self.partials.slice(t * self.sums + k as usize, 1) };
                    partial[0] = sum::forward_tile(x);
                }
                Op::ScatterAdd if sinks => {
                    let Out::Scatter(s, a) = ins.out else { unreachable!() };
                    let target = self.accumulator(tile, s, self.vals[a as usize]);
                    scatter_add::forward_tile(self.value(tile, ins.ins[0]), self.value(tile, ins.ins[1]), target);
                }
                _ => {}
            }
        }
    }

    /// Runs the gathers of a group (see [`GatherGroup`]) in one loop. The
    /// later members' outputs are written early, which is harmless: nothing
    /// reads them before their turn.
    fn gather_group(&self, tile: &Tile<'_, T>, at: GatherGroup, nf: &mut Option<NonFinite>) {
        let members = &self.group_members[at.start as usize..(at.start + at.len) as usize];
        let lead = &self.instrs[members[0] as usize];
        let Src::Array(s) = lead.ins[0] else {
            unreachable!("gather sources are arrays")
        };
        // SAFETY: the source is complete and only read.
        let source = unsafe { self.vals[s as usize].slice(0, self.vals[s as usize].len) };
        let outputs = members.iter().map(|&j| {
            let ins = &self.instrs[j as usize];
            let Op::Gather { stride, offset } = self.nodes[ins.node as usize].op else {
                unreachable!("a gather group holds gathers")
            };
            (stride, offset, self.out_mut(tile, ins.out))
        });
        gather::forward_tile(source, self.value(tile, lead.ins[1]), outputs);
        if self.check_finite && nf.is_none() {
            for &j in members {
                let ins = &self.instrs[j as usize];
                let y = self.value(tile, Self::out_src(ins.out));
                if let Some(found) = first_non_finite(y, ins.node, "gather", tile.t0, false) {
                    *nf = Some(found);
                    break;
                }
            }
        }
    }

    /// Chunk 0 accumulates into the real buffer, the others into their private copy.
    #[inline(always)]
    fn accumulator<'b>(&self, tile: &Tile<'_, T>, s: u32, real: Ptr<T>) -> &'b mut [T] {
        let p = if tile.chunk == 0 {
            real
        } else {
            tile.privates[s as usize]
        };
        // SAFETY: chunk 0 is the only writer of the real buffer during the run.
        unsafe { p.slice(0, p.len) }
    }

    /// The tile of an op's output, to write.
    #[inline(always)]
    fn out_mut<'b>(&self, tile: &Tile<'_, T>, out: Out) -> &'b mut [T] {
        // SAFETY: a node's output slot or tile range is written by this chunk only.
        unsafe {
            match out {
                Out::Slot(k) => tile.vals.slice(k as usize * self.tile_len, tile.n),
                Out::Array(a) => self.vals[a as usize].slice(tile.t0, tile.n),
                Out::Sum(..) | Out::Scatter(..) => unreachable!("sinks have no tile output"),
            }
        }
    }

    /// Vector-Jacobian products over one tile, in reverse.
    fn backward_tile(&self, tile: &Tile<'_, T>, bcast_grads: &mut [T], nf: &mut Option<NonFinite>) {
        let tl = self.tile_len;
        for (j, ins) in self.instrs.iter().enumerate().rev() {
            let id = ins.node as usize;
            let accumulate = |k: usize| self.overwrite[j] & (1 << k) == 0;
            if !self.live[id] {
                continue;
            }
            let node = &self.nodes[id];
            let first = node.first_input as usize;
            let live_input = |k: usize| self.live[self.edges[first + k] as usize];
            match node.op {
                Op::Sum => {
                    let Out::Sum(_, a) = ins.out else { unreachable!() };
                    // SAFETY: the sum's adjoint exists (it is live) and is only read.
                    let gy = unsafe { self.adjs[a as usize].slice(0, 1) }[0];
                    if let Some(gx) = self.adjoint(tile, ins.ins[0]) {
                        sum::backward_tile(gy, gx, accumulate(0));
                    }
                }
                Op::ScatterAdd => {
                    let Out::Scatter(_, a) = ins.out else { unreachable!() };
                    // SAFETY: as above.
                    let gy = unsafe { self.adjs[a as usize].slice(0, self.adjs[a as usize].len) };
                    if let Some(gx) = self.adjoint(tile, ins.ins[0]) {
                        scatter_add::backward_tile(gy, self.value(tile, ins.ins[1]), gx, accumulate(0));
                    }
                }
                Op::Map(kind, p) => {
                    let out = Self::out_src(ins.out);
                    let y = self.value(tile, out);
                    let Some(gy) = self.adjoint(tile, out) else { continue };
                    let x = [
                        self.value(tile, ins.ins[0]),
                        self.value(tile, ins.ins[1]),
                        self.value(tile, ins.ins[2]),
                    ];
                    for k in 0..kind.arity() {
                        if !live_input(k) {
                            continue;
                        }
                        if let Some(gx) = self.adjoint(tile, ins.ins[k]) {
                            kind.backward(k, accumulate(k), x, y, gy, gx, p);
                            if self.check_finite && nf.is_none() {
                                *nf = first_non_finite(gx, ins.node, kind.name(), tile.t0, true);
                            }
                        }
                    }
                }
                // Deferred: see below.
                _ => {}
            }
        }
        // Gathers scatter their adjoints last, all gathers from one array in
        // one interleaved loop: the texels that neighbouring lookups read (RGB
        // channels, bilinear corners) share cache lines.
        for (pos, &(s, scatter)) in self.shared.iter().enumerate() {
            if scatter || self.adjs[s as usize].ptr.is_null() {
                continue;
            }
            let gathers = self.instrs.iter().filter_map(|ins| {
                let Op::Gather { stride, offset } = self.nodes[ins.node as usize].op else {
                    return None;
                };
                if !matches!(ins.ins[0], Src::Array(a) if a == s) || !self.live[ins.node as usize] {
                    return None;
                }
                let gy = self.adjoint(tile, Self::out_src(ins.out))?;
                Some((stride, offset, self.value(tile, ins.ins[1]), &*gy))
            });
            gather::backward_tile(
                self.accumulator(tile, pos as u32, self.adjs[s as usize]),
                tile.n,
                gathers,
            );
        }
        for (b, acc) in bcast_grads.iter_mut().enumerate() {
            if !self.live[self.bcast_nodes[b] as usize] {
                continue;
            }
            // SAFETY: this chunk's scratch.
            let g = unsafe { tile.adjs.slice((self.slots + b) * tl, tile.n) };
            *acc += sum::tile_sum(g);
        }
    }
}

/// One tile of a chunk's run.
struct Tile<'p, T> {
    t0: usize,
    n: usize,
    vals: Ptr<T>,
    adjs: Ptr<T>,
    privates: &'p [Ptr<T>],
    chunk: usize,
}

/// Raw view of a buffer shared by the chunks of a region's run. Chunks write
/// disjoint tile ranges of it, or (accumulating targets) only chunk 0 does.
#[derive(Clone, Copy)]
pub(super) struct Ptr<T> {
    ptr: *mut T,
    pub(super) len: usize,
}

// SAFETY: see the struct's comment: concurrent accesses never overlap.
unsafe impl<T: Send> Send for Ptr<T> {}
unsafe impl<T: Sync> Sync for Ptr<T> {}

impl<T> Ptr<T> {
    const NULL: Ptr<T> = Ptr {
        ptr: std::ptr::null_mut(),
        len: 0,
    };
    pub(super) fn of(v: &mut [T]) -> Self {
        Ptr {
            ptr: v.as_mut_ptr(),
            len: v.len(),
        }
    }
    /// Elements `start..start + n`.
    ///
    /// SAFETY: the range is in bounds, and no other live reference overlaps it
    /// mutably (the executor's invariants).
    #[inline(always)]
    pub(super) unsafe fn slice<'a>(self, start: usize, n: usize) -> &'a mut [T] {
        debug_assert!(start + n <= self.len);
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), n) }
    }
}
