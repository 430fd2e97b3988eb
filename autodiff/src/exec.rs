//! The executor: plans pending nodes into steps and runs them.
//!
//! A *region* is a run of consecutive nodes over one domain of `len`
//! elements: elementwise maps, gathers from arrays computed earlier, and the
//! sums and scatter-adds that end the chain (its *sinks*). A region runs tile
//! by tile (256 to 1024 elements, fewer for longer chains so that a tile's
//! values and adjoints stay in L2): every op of the chain is applied to one tile
//! before the next tile starts, so the intermediates stay in cache instead of
//! streaming through main memory. Only values that leave the region (used by
//! a later step, or asked for) are written to full-length buffers; the rest
//! live in tile *slots*, and the backward pass recomputes them tile by tile
//! before it runs the chain's vector-Jacobian products in reverse. Small
//! regions keep every value instead (nothing to recompute).
//!
//! Long regions are cut into a fixed number of contiguous chunks of tiles,
//! run on rayon's threads. Values that several chunks accumulate into
//! (gradients of gathered-from arrays and of broadcast scalars, scatter-add
//! outputs) get a private buffer per extra chunk, reduced in chunk order at
//! the end; sums are reduced per tile and added in tile order. The cut
//! depends only on the length, so results are bit-identical for any number
//! of threads.
//!
//! Everything else (slice, concat, custom ops) runs as a *plain* step over
//! whole arrays.

use std::ops::Range;

use rayon::prelude::*;

use crate::ops::{add_into, concat, custom, gather, scatter_add, slice, sum};
use crate::real::Real;
use crate::tape::{Graph, NONE, Node, NonFinite, Op};

/// Most elements per tile.
pub(crate) const TILE: usize = 1024;
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
/// Regions whose values total at most this many elements keep them all
/// (no recomputation in the backward pass).
const KEEP_ALL_ELEMENTS: usize = 1 << 16;

/// Where an op reads one of its inputs during a region's run.
#[derive(Clone, Copy, Debug)]
enum Src {
    /// A tile slot of a value computed in this region.
    Slot(u32),
    /// A full-length buffer (index into the region's array table).
    Array(u32),
    /// A length-1 array broadcast over the tile (index into the region's broadcasts).
    Bcast(u32),
}

/// Where an op writes its output during a region's run.
#[derive(Clone, Copy, Debug)]
enum Out {
    Slot(u32),
    /// Full-length buffer: array-table index.
    Array(u32),
    /// Sum sink: index of its per-tile partials, array-table index of its value.
    Sum(u32, u32),
    /// Scatter-add sink: index among the region's accumulated targets, array-table index.
    Scatter(u32, u32),
}

#[derive(Clone, Copy, Debug)]
struct Instr {
    node: u32,
    ins: [Src; 3],
    out: Out,
    /// A gather's group in its region's part of `Executor::group_members`,
    /// for a full forward pass and for a recompute ([`GatherGroup::NONE`]
    /// elsewhere).
    groups: [GatherGroup; 2],
}

/// The gathers that run in one loop with a lead gather: the later gathers
/// of its region that read the same array at the same indices (the
/// channels of a texel), the lead first. Found once when the region is
/// built: searched in every tile, the search took 5.6 % of `alp estimate`'s
/// time on the upright courtyard can's twin at its true pose (perf).
#[derive(Clone, Copy, Debug)]
struct GatherGroup {
    start: u32,
    /// 0: not a lead (run with an earlier gather of its group, or not at all).
    len: u32,
}

impl GatherGroup {
    const NONE: GatherGroup = GatherGroup { start: 0, len: 0 };
}

#[derive(Clone, Debug)]
struct Region {
    len: usize,
    nodes: Range<u32>,
    instrs: Range<usize>,
    /// Node ids of the region's full-length arrays (external inputs, kept values, sinks).
    arrays: Range<usize>,
    /// Node ids of the broadcast scalars.
    bcasts: Range<usize>,
    /// Arrays that several chunks accumulate into: (array-table index,
    /// whether it is a scatter output (forward) or a gather source (backward)).
    shared: Range<usize>,
    /// Its gathers' groups (instruction indices within the region).
    group_members: Range<usize>,
    slots: usize,
    sums: usize,
}

#[derive(Clone, Copy, Debug)]
enum Step {
    Region(u32),
    Plain(u32),
}

/// Raw view of a buffer shared by the chunks of a region's run. Chunks write
/// disjoint tile ranges of it, or (accumulating targets) only chunk 0 does.
#[derive(Clone, Copy)]
struct Ptr<T> {
    ptr: *mut T,
    len: usize,
}
// SAFETY: see the struct's comment: concurrent accesses never overlap.
unsafe impl<T: Send> Send for Ptr<T> {}
unsafe impl<T: Sync> Sync for Ptr<T> {}

impl<T> Ptr<T> {
    const NULL: Ptr<T> = Ptr {
        ptr: std::ptr::null_mut(),
        len: 0,
    };
    fn of(v: &mut [T]) -> Self {
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
    unsafe fn slice<'a>(self, start: usize, n: usize) -> &'a mut [T] {
        debug_assert!(start + n <= self.len);
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), n) }
    }
}

/// Per-chunk scratch: tile slots for values and adjoints, private
/// accumulation buffers, broadcast-gradient sums, the first non-finite value.
#[derive(Default)]
struct Chunk<T> {
    vals: Vec<T>,
    adjs: Vec<T>,
    privates: Vec<Vec<T>>,
    /// Views of `privates` for the tiles (kept to reuse the allocation).
    private_ptrs: Vec<Ptr<T>>,
    bcast_grads: Vec<T>,
    non_finite: Option<NonFinite>,
}

/// Planner state and scratch, owned by the graph.
pub(crate) struct Executor<T> {
    steps: Vec<Step>,
    regions: Vec<Region>,
    instrs: Vec<Instr>,
    group_members: Vec<u32>,
    /// Scratch of `group_gathers`: per instruction, whether it joined a group.
    grouped: Vec<bool>,
    arrays: Vec<u32>,
    bcasts: Vec<u32>,
    shared: Vec<(u32, bool)>,
    /// Node id -> index in the region being built (NONE elsewhere).
    local: Vec<u32>,
    live: Vec<bool>,
    overwrite: Vec<u8>,
    touched: Vec<bool>,
    partials: Vec<f64>,
    chunks: Vec<Chunk<T>>,
    vals: Vec<Ptr<T>>,
    adjs: Vec<Ptr<T>>,
    bcast_values: Vec<T>,
}

impl<T> Default for Executor<T> {
    fn default() -> Self {
        Executor {
            steps: Vec::new(),
            regions: Vec::new(),
            instrs: Vec::new(),
            group_members: Vec::new(),
            grouped: Vec::new(),
            arrays: Vec::new(),
            bcasts: Vec::new(),
            shared: Vec::new(),
            local: Vec::new(),
            live: Vec::new(),
            overwrite: Vec::new(),
            touched: Vec::new(),
            partials: Vec::new(),
            chunks: Vec::new(),
            vals: Vec::new(),
            adjs: Vec::new(),
            bcast_values: Vec::new(),
        }
    }
}

impl<T: Real> Executor<T> {
    /// Forgets the steps of nodes at or after `end`.
    pub(crate) fn truncate(&mut self, end: u32, nodes: &mut [Node<T>]) {
        while let Some(&step) = self.steps.last() {
            let first = match step {
                Step::Region(r) => self.regions[r as usize].nodes.start,
                Step::Plain(n) => n,
            };
            if first < end {
                break;
            }
            self.steps.pop();
            if let Step::Region(r) = step {
                let reg = self.regions.pop().expect("a region step has a region");
                debug_assert_eq!(r as usize, self.regions.len());
                self.instrs.truncate(reg.instrs.start);
                self.group_members.truncate(reg.group_members.start);
                self.arrays.truncate(reg.arrays.start);
                self.bcasts.truncate(reg.bcasts.start);
                self.shared.truncate(reg.shared.start);
            }
        }
        debug_assert!(
            nodes
                .iter()
                .all(|n| n.step == NONE || (n.step as usize) < self.steps.len())
        );
    }

    /// Marks, for the region's backward pass, each contribution that is the
    /// first (in reverse order) to its tile slot: it writes instead of adding.
    fn overwrite_flags(&mut self, nodes: &[Node<T>], edges: &[u32], reg: &Region) {
        let instrs = &self.instrs[reg.instrs.clone()];
        self.overwrite.clear();
        self.overwrite.resize(instrs.len(), 0);
        self.touched.clear();
        self.touched
            .resize(reg.slots + reg.bcasts.len() + reg.arrays.len(), false);
        for (j, ins) in instrs.iter().enumerate().rev() {
            let node = &nodes[ins.node as usize];
            if !self.live[ins.node as usize] {
                continue;
            }
            let inputs = match node.op {
                Op::Map(kind, _) => kind.arity(),
                Op::Sum | Op::ScatterAdd => 1,
                _ => 0,
            };
            for k in 0..inputs {
                if !self.live[edges[node.first_input as usize + k] as usize] {
                    continue;
                }
                let target = match ins.ins[k] {
                    Src::Slot(s) => s as usize,
                    Src::Bcast(b) => reg.slots + b as usize,
                    Src::Array(a) if nodes[self.arrays[reg.arrays.start + a as usize] as usize].fresh => {
                        reg.slots + reg.bcasts.len() + a as usize
                    }
                    Src::Array(_) => continue,
                };
                if !self.touched[target] {
                    self.touched[target] = true;
                    self.overwrite[j] |= 1 << k;
                }
            }
        }
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
            let dst = if pass.backward() {
                self.adjs[target as usize]
            } else {
                self.vals[target as usize]
            };
            let wanted = if scatter { pass.forward_sinks() } else { pass.backward() };
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
}

/// The length of the domain a tileable node iterates over, or None for plain ops.
fn domain_len<T: Real>(g: &Graph<T>, id: u32) -> Option<usize> {
    let n = &g.nodes[id as usize];
    match n.op {
        Op::Map(..) | Op::Gather { .. } => Some(n.len as usize),
        Op::Sum | Op::ScatterAdd => Some(g.nodes[g.inputs(id)[0] as usize].len as usize),
        _ => None,
    }
}

fn is_sink<T>(op: &Op<T>) -> bool {
    matches!(op, Op::Sum | Op::ScatterAdd)
}

fn is_input<T>(op: &Op<T>) -> bool {
    matches!(op, Op::Leaf | Op::Constant)
}

impl<T: Real> Graph<T> {
    /// Plans and runs every pending node; `want` must end up in a buffer.
    pub(crate) fn execute(&mut self, want: Option<u32>) {
        self.run_pending(want, None);
    }

    /// [`execute`](Self::execute), except that when `fuse` (a pending sum) ends
    /// up in the last region, that region is only built, not run: its index
    /// is returned so that the caller runs it forward and backward in one pass.
    fn run_pending(&mut self, want: Option<u32>, fuse: Option<u32>) -> Option<usize> {
        let start = self.executed;
        if let Some(w) = want
            && (w as usize) < start
            && self.nodes[w as usize].value == NONE
        {
            self.rematerialize(w);
        }
        for id in start..self.nodes.len() {
            for k in 0..self.nodes[id].num_inputs {
                let i = self.edges[(self.nodes[id].first_input + k) as usize];
                if (i as usize) < start && self.nodes[i as usize].value == NONE {
                    self.rematerialize(i);
                }
            }
        }
        if start == self.nodes.len() {
            return None;
        }
        let first_step = self.exec.steps.len();
        self.plan(start, want);
        self.executed = self.nodes.len();
        let last = self.exec.steps.len() - 1;
        for s in first_step..=last {
            match self.exec.steps[s] {
                Step::Region(r) => {
                    self.build_region(r as usize);
                    if s == last && fuse.is_some_and(|f| self.nodes[f as usize].step as usize == s) {
                        return Some(r as usize);
                    }
                    self.run_region(r as usize, Pass::Forward { sinks: true });
                }
                Step::Plain(id) => self.plain_forward(id),
            }
        }
        None
    }

    /// Assigns pending nodes to steps and decides which values get buffers.
    fn plan(&mut self, start: usize, want: Option<u32>) {
        let end = self.nodes.len();
        let mut open: Option<u32> = None;
        for id in start as u32..end as u32 {
            let op = self.nodes[id as usize].op;
            if is_input(&op) {
                continue;
            }
            let domain = domain_len(self, id);
            if let (Some(r), Some(len)) = (open, domain)
                && self.fits(r, id, len)
            {
                let region = &mut self.exec.regions[r as usize];
                self.nodes[id as usize].step = self.nodes[region.nodes.start as usize].step;
                region.nodes.end = id + 1;
                continue;
            }
            let step = self.exec.steps.len() as u32;
            self.nodes[id as usize].step = step;
            match domain {
                Some(len) => {
                    let r = self.exec.regions.len() as u32;
                    self.exec.regions.push(Region {
                        len,
                        nodes: id..id + 1,
                        instrs: 0..0,
                        group_members: 0..0,
                        arrays: 0..0,
                        bcasts: 0..0,
                        shared: 0..0,
                        slots: 0,
                        sums: 0,
                    });
                    self.exec.steps.push(Step::Region(r));
                    open = Some(r);
                }
                None => {
                    self.exec.steps.push(Step::Plain(id));
                    self.nodes[id as usize].materialize = true;
                    open = None;
                }
            }
        }
        for id in start..end {
            let n = self.nodes[id];
            if is_input(&n.op) {
                continue;
            }
            for k in 0..n.num_inputs {
                let i = self.edges[(n.first_input + k) as usize] as usize;
                let inp = &self.nodes[i];
                if !is_input(&inp.op) && i >= start && inp.step != n.step {
                    self.nodes[i].materialize = true;
                }
            }
            if is_sink(&n.op) {
                self.nodes[id].materialize = true;
            }
        }
        if let Some(w) = want {
            self.nodes[w as usize].materialize = true;
        }
    }

    /// Whether pending node `id` (domain `len`) can join the open region `r`.
    fn fits(&self, r: u32, id: u32, len: usize) -> bool {
        let reg = &self.exec.regions[r as usize];
        if len != reg.len {
            return false;
        }
        let step = self.nodes[reg.nodes.start as usize].step;
        let op = self.nodes[id as usize].op;
        self.inputs(id).iter().enumerate().all(|(k, &i)| {
            let inp = &self.nodes[i as usize];
            let member = inp.step == step && !is_input(&inp.op) && (i as usize) >= self.executed;
            // A sink's value is complete only after the region: its users start a new one.
            // A gather reads its whole source: the source must be complete too.
            !(member && (is_sink(&inp.op) || (matches!(op, Op::Gather { .. }) && k == 0)))
        })
    }

    /// Index of node `i` in the region's array table, added on first use.
    fn array_of(&mut self, i: u32, base: usize) -> u32 {
        if self.exec.local.len() < self.nodes.len() {
            self.exec.local.resize(self.nodes.len(), NONE);
        }
        if self.exec.local[i as usize] == NONE {
            self.exec.local[i as usize] = (self.exec.arrays.len() - base) as u32;
            self.exec.arrays.push(i);
        }
        self.exec.local[i as usize]
    }

    /// Builds region `r`'s instructions from its members' materialize flags
    /// (called again when a member is rematerialised).
    fn build_region(&mut self, r: usize) {
        let reg = self.exec.regions[r].clone();
        let step = self.nodes[reg.nodes.start as usize].step;
        let keep_all = {
            let members = (reg.nodes.start..reg.nodes.end)
                .filter(|&i| self.nodes[i as usize].step == step && !is_input(&self.nodes[i as usize].op))
                .count();
            members * reg.len <= KEEP_ALL_ELEMENTS
        };
        let (i0, a0, b0) = (self.exec.instrs.len(), self.exec.arrays.len(), self.exec.bcasts.len());
        let s0 = self.exec.shared.len();
        let (mut slots, mut sums) = (0u32, 0u32);
        for id in reg.nodes.clone() {
            let n = self.nodes[id as usize];
            if n.step != step || is_input(&n.op) {
                continue;
            }
            let mut ins = [Src::Slot(0); 3];
            let num = n.num_inputs as usize;
            for (k, src) in ins.iter_mut().enumerate().take(num) {
                *src = self.input_src(&n, k, reg.len, a0, b0);
            }
            // Unused input positions read the first input (never written).
            for k in num..3 {
                ins[k] = ins[0];
            }
            if let Op::Gather { .. } = n.op {
                let Src::Array(src) = ins[0] else {
                    unreachable!("gather sources are arrays")
                };
                if !self.exec.shared[s0..].contains(&(src, false)) {
                    self.exec.shared.push((src, false));
                }
            }
            let out = match n.op {
                Op::Sum | Op::ScatterAdd => {
                    if n.value == NONE {
                        let b = self.values.take(n.len as usize);
                        self.nodes[id as usize].value = b;
                    }
                    let a = self.array_of(id, a0);
                    if let Op::Sum = n.op {
                        sums += 1;
                        Out::Sum(sums - 1, a)
                    } else {
                        self.exec.shared.push((a, true));
                        Out::Scatter((self.exec.shared.len() - s0 - 1) as u32, a)
                    }
                }
                _ if n.materialize || keep_all => {
                    if n.value == NONE {
                        let b = self.values.take(n.len as usize);
                        self.nodes[id as usize].value = b;
                    }
                    Out::Array(self.array_of(id, a0))
                }
                _ => {
                    self.nodes[id as usize].slot = slots;
                    slots += 1;
                    Out::Slot(slots - 1)
                }
            };
            self.exec.instrs.push(Instr {
                node: id,
                ins,
                out,
                groups: [GatherGroup::NONE; 2],
            });
        }
        let g0 = self.exec.group_members.len();
        for recompute in [false, true] {
            self.group_gathers(i0, g0, recompute);
        }
        for &a in &self.exec.arrays[a0..] {
            self.exec.local[a as usize] = NONE;
        }
        let reg = &mut self.exec.regions[r];
        reg.instrs = i0..self.exec.instrs.len();
        reg.arrays = a0..self.exec.arrays.len();
        reg.bcasts = b0..self.exec.bcasts.len();
        reg.shared = s0..self.exec.shared.len();
        reg.group_members = g0..self.exec.group_members.len();
        reg.slots = slots as usize;
        reg.sums = sums as usize;
    }

    /// Where a member `n` of the region being built (domain `len`, array and
    /// broadcast tables from `a0` and `b0`) reads its input `k`: a tile slot
    /// of a value computed in the region, a full-length buffer, or a
    /// broadcast scalar.
    fn input_src(&mut self, n: &Node<T>, k: usize, len: usize, a0: usize, b0: usize) -> Src {
        let i = self.edges[n.first_input as usize + k];
        let inp = self.nodes[i as usize];
        if inp.step == n.step && !is_input(&inp.op) && inp.value == NONE {
            Src::Slot(inp.slot)
        } else if inp.len as usize == len || (matches!(n.op, Op::Gather { .. }) && k == 0) {
            Src::Array(self.array_of(i, a0))
        } else {
            debug_assert_eq!(inp.len, 1);
            if self.exec.local.len() < self.nodes.len() {
                self.exec.local.resize(self.nodes.len(), NONE);
            }
            // Broadcasts share the local table; mark them apart by range.
            let pos = self.exec.bcasts[b0..].iter().position(|&b| b == i);
            Src::Bcast(match pos {
                Some(p) => p as u32,
                None => {
                    self.exec.bcasts.push(i);
                    (self.exec.bcasts.len() - b0 - 1) as u32
                }
            })
        }
    }

    /// Groups the gathers of the region whose instructions begin at `i0`
    /// and whose groups at `g0` (see [`GatherGroup`]): for a recompute,
    /// only those whose values live in slots.
    fn group_gathers(&mut self, i0: usize, g0: usize, recompute: bool) {
        let nodes = &self.nodes;
        let ex = &mut self.exec;
        let eligible = |ins: &Instr| {
            matches!(nodes[ins.node as usize].op, Op::Gather { .. }) && (!recompute || matches!(ins.out, Out::Slot(_)))
        };
        let n = ex.instrs.len() - i0;
        let grouped = &mut ex.grouped;
        grouped.clear();
        grouped.resize(n, false);
        for j in 0..n {
            let lead = ex.instrs[i0 + j];
            if grouped[j] || !eligible(&lead) {
                continue;
            }
            let start = ex.group_members.len();
            ex.group_members.push(j as u32);
            for (k, ins) in ex.instrs[i0..].iter().enumerate().skip(j + 1) {
                if ex.group_members.len() - start == gather::GROUP {
                    break;
                }
                if eligible(ins) && same_src(ins.ins[0], lead.ins[0]) && same_src(ins.ins[1], lead.ins[1]) {
                    ex.group_members.push(k as u32);
                    grouped[k] = true;
                }
            }
            ex.instrs[i0 + j].groups[recompute as usize] = GatherGroup {
                start: (start - g0) as u32,
                len: (ex.group_members.len() - start) as u32,
            };
        }
    }

    /// Gives an executed node whose value lived only in tiles a buffer, by
    /// running its region's forward pass again (sinks are not re-accumulated).
    pub(crate) fn rematerialize(&mut self, id: u32) {
        let step = self.nodes[id as usize].step;
        if step == NONE {
            return;
        }
        let Step::Region(r) = self.exec.steps[step as usize] else {
            unreachable!("plain steps always write buffers")
        };
        self.nodes[id as usize].materialize = true;
        self.build_region(r as usize);
        self.run_region(r as usize, Pass::Forward { sinks: false });
    }

    fn plain_forward(&mut self, id: u32) {
        let n = self.nodes[id as usize];
        let out = self.values.take(n.len as usize);
        self.nodes[id as usize].value = out;
        let (first, num) = (n.first_input as usize, n.num_inputs as usize);
        let mut bufs = std::mem::take(&mut self.values.bufs);
        let mut out_buf = std::mem::take(&mut bufs[out as usize]);
        let input = |k: usize| -> &[T] {
            let i = &self.nodes[self.edges[first + k] as usize];
            &bufs[i.value as usize][..i.len as usize]
        };
        match n.op {
            Op::Slice(start) => slice::forward(input(0), start as usize, &mut out_buf),
            Op::Concat => concat::forward((0..num).map(input), &mut out_buf),
            Op::Custom(c) => custom::forward(&*self.customs[c as usize], (0..num).map(input), &mut out_buf),
            _ => unreachable!("only plain ops run as plain steps"),
        }
        if self.check_finite && self.non_finite.is_none() {
            self.non_finite = first_non_finite(&out_buf, id, n.op.name(), 0, false);
        }
        bufs[out as usize] = out_buf;
        self.values.bufs = bufs;
    }

    /// Reverse sweep from `output` (length 1).
    pub(crate) fn backward(&mut self, output: u32) {
        // A loss that is the sum ending the last pending region has adjoint 1
        // before its value is known: that region runs forward and backward
        // in one pass over its tiles (no recomputation).
        let pending_sum = output as usize >= self.executed && matches!(self.nodes[output as usize].op, Op::Sum);
        let fused = self.run_pending(Some(output), pending_sum.then_some(output));
        self.adjoints.used = 0;
        for n in &mut self.nodes {
            n.adjoint = NONE;
        }
        let ex = &mut self.exec;
        ex.live.clear();
        ex.live.resize(self.nodes.len(), false);
        ex.live[output as usize] = self.nodes[output as usize].requires_grad;
        for id in (0..=output as usize).rev() {
            if ex.live[id] {
                let n = &self.nodes[id];
                for &i in &self.edges[n.first_input as usize..(n.first_input + n.num_inputs) as usize] {
                    if self.nodes[i as usize].requires_grad {
                        ex.live[i as usize] = true;
                    }
                }
            }
        }
        let seed = self.adjoints.take_zeroed(1);
        self.adjoints.bufs[seed as usize][0] = T::one();
        self.nodes[output as usize].adjoint = seed;
        if !self.exec.live[output as usize] {
            if let Some(r) = fused {
                self.run_region(r, Pass::Forward { sinks: true });
            }
            self.zero_missing_leaf_gradients();
            return;
        }
        if let Some(r) = fused {
            self.run_region(r, Pass::Fused);
        }
        for s in (0..self.exec.steps.len()).rev() {
            match self.exec.steps[s] {
                Step::Region(r) if Some(r as usize) == fused => {}
                Step::Region(r) => {
                    let nodes = self.exec.regions[r as usize].nodes.clone();
                    if nodes.start > output {
                        continue;
                    }
                    let end = nodes.end.min(output + 1);
                    if (nodes.start..end).any(|i| self.exec.live[i as usize]) {
                        self.run_region(r as usize, Pass::Backward);
                    }
                }
                Step::Plain(id) => {
                    if id <= output && self.exec.live[id as usize] {
                        self.plain_backward(id);
                    }
                }
            }
        }
        self.zero_missing_leaf_gradients();
    }

    /// Every leaf gets a gradient, zero where the output does not depend on it.
    fn zero_missing_leaf_gradients(&mut self) {
        for id in 0..self.nodes.len() as u32 {
            if matches!(self.nodes[id as usize].op, Op::Leaf) {
                self.adjoint_of(id);
            }
        }
    }

    /// The adjoint buffer of node `i`, zeroed on first use.
    fn adjoint_of(&mut self, i: u32) -> u32 {
        if self.nodes[i as usize].adjoint == NONE {
            let len = self.nodes[i as usize].len as usize;
            self.nodes[i as usize].adjoint = self.adjoints.take_zeroed(len);
        }
        self.nodes[i as usize].adjoint
    }

    fn plain_backward(&mut self, id: u32) {
        let n = self.nodes[id as usize];
        let (first, num) = (n.first_input as usize, n.num_inputs as usize);
        for k in 0..num {
            let i = self.edges[first + k];
            if self.exec.live[i as usize] {
                self.adjoint_of(i);
            }
        }
        let mut adj = std::mem::take(&mut self.adjoints.bufs);
        let gy_buf = std::mem::take(&mut adj[n.adjoint as usize]);
        let input_grad = |adj: &mut Vec<Vec<T>>, k: usize| -> Option<Ptr<T>> {
            let i = self.edges[first + k] as usize;
            self.exec.live[i].then(|| Ptr::of(&mut adj[self.nodes[i].adjoint as usize][..self.nodes[i].len as usize]))
        };
        let gy = &gy_buf[..n.len as usize];
        match n.op {
            Op::Slice(start) => {
                if let Some(g) = input_grad(&mut adj, 0) {
                    // SAFETY: `g` is the only reference to that buffer.
                    slice::backward(gy, start as usize, unsafe { g.slice(0, g.len) });
                }
            }
            Op::Concat => {
                let parts = (0..num).map(|k| {
                    let len = self.nodes[self.edges[first + k] as usize].len as usize;
                    // SAFETY: concat uses each part's gradient before it takes the next.
                    (len, input_grad(&mut adj, k).map(|g| unsafe { g.slice(0, len) }))
                });
                concat::backward(gy, parts);
            }
            Op::Custom(c) => {
                let vals = &self.values.bufs;
                let inputs = (0..num).map(|k| {
                    let i = &self.nodes[self.edges[first + k] as usize];
                    // SAFETY: distinct inputs have distinct adjoint buffers; an
                    // input repeated in the list gets its gradient slot once.
                    let repeated = (0..k).any(|j| self.edges[first + j] == self.edges[first + k]);
                    let g = if repeated { None } else { input_grad(&mut adj, k) };
                    (
                        &vals[i.value as usize][..i.len as usize],
                        g.map(|g| unsafe { g.slice(0, i.len as usize) }),
                    )
                });
                let y = &vals[n.value as usize][..n.len as usize];
                custom::backward(&*self.customs[c as usize], inputs, y, gy);
            }
            _ => unreachable!("only plain ops run as plain steps"),
        }
        adj[n.adjoint as usize] = gy_buf;
        self.adjoints.bufs = adj;
    }

    /// Runs region `r` forward (optionally without its sinks) or backward.
    fn run_region(&mut self, r: usize, pass: Pass) {
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

/// Which pass a region runs.
#[derive(Clone, Copy, Debug)]
enum Pass {
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

fn same_src(a: Src, b: Src) -> bool {
    match (a, b) {
        (Src::Slot(x), Src::Slot(y)) | (Src::Array(x), Src::Array(y)) | (Src::Bcast(x), Src::Bcast(y)) => x == y,
        _ => false,
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

fn first_non_finite<T: Real>(
    x: &[T],
    node: u32,
    op: &'static str,
    offset: usize,
    in_backward: bool,
) -> Option<NonFinite> {
    x.iter().position(|v| !v.is_finite()).map(|k| NonFinite {
        node: node as usize,
        op,
        index: offset + k,
        value: x[k].f64(),
        in_backward,
    })
}
