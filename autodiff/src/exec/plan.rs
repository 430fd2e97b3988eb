//! Planning: which pending nodes form a region, and each region's
//! instructions.
//!
//! Consecutive nodes over one domain join a region unless an input is a
//! member whose value is complete only after the region (a sink's, or a
//! gather's source). A region's members become instructions that name where
//! each input is read (tile slot, full-length buffer, broadcast scalar) and
//! where the output goes (slot, buffer, or a sink's sum partials or
//! scatter target); gathers that share a source and indices are grouped,
//! and a backward pass's first contribution to each slot is marked to write
//! instead of adding.

use std::ops::Range;

use super::{Executor, Step};
use super::{Graph, NONE, Node, Op};
use crate::kernels::gather;
use crate::real::Real;

/// Regions whose values total at most this many elements keep them all
/// (no recomputation in the backward pass).
const KEEP_ALL_ELEMENTS: usize = 1 << 16;

/// Where an op reads one of its inputs during a region's run.
#[derive(Clone, Copy, Debug)]
pub(super) enum Src {
    /// A tile slot of a value computed in this region.
    Slot(u32),
    /// A full-length buffer (index into the region's array table).
    Array(u32),
    /// A length-1 array broadcast over the tile (index into the region's broadcasts).
    Bcast(u32),
}

/// Where an op writes its output during a region's run.
#[derive(Clone, Copy, Debug)]
pub(super) enum Out {
    Slot(u32),
    /// Full-length buffer: array-table index.
    Array(u32),
    /// Sum sink: index of its per-tile partials, array-table index of its value.
    Sum(u32, u32),
    /// Scatter-add sink: index among the region's accumulated targets, array-table index.
    Scatter(u32, u32),
}

/// One member of a region: its node, where it reads its inputs and where
/// it writes its output.
#[derive(Clone, Copy, Debug)]
pub(super) struct Instr {
    pub(super) node: u32,
    pub(super) ins: [Src; 3],
    pub(super) out: Out,
    /// A gather's group in its region's part of `Executor::group_members`,
    /// for a full forward pass and for a recompute ([`GatherGroup::NONE`]
    /// elsewhere).
    pub(super) groups: [GatherGroup; 2],
}

/// The gathers that run in one loop with a lead gather: the later gathers
/// of its region that read the same array at the same indices (the
/// channels of a texel), the lead first. Found once when the region is
/// built, not searched again in every tile.
#[derive(Clone, Copy, Debug)]
pub(super) struct GatherGroup {
    pub(super) start: u32,
    /// 0: not a lead (run with an earlier gather of its group, or not at all).
    pub(super) len: u32,
}

impl GatherGroup {
    pub(super) const NONE: GatherGroup = GatherGroup { start: 0, len: 0 };
}

/// Consecutive nodes over one domain of `len` elements, run tile by tile;
/// its instructions and tables are ranges of the executor's shared vectors.
#[derive(Clone, Debug)]
pub(super) struct Region {
    pub(super) len: usize,
    pub(super) nodes: Range<u32>,
    pub(super) instrs: Range<usize>,
    /// Node ids of the region's full-length arrays (external inputs, kept values, sinks).
    pub(super) arrays: Range<usize>,
    /// Node ids of the broadcast scalars.
    pub(super) bcasts: Range<usize>,
    /// Arrays that several chunks accumulate into: (array-table index,
    /// whether it is a scatter output (forward) or a gather source (backward)).
    pub(super) shared: Range<usize>,
    /// Its gathers' groups (instruction indices within the region).
    pub(super) group_members: Range<usize>,
    pub(super) slots: usize,
    pub(super) sums: usize,
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

/// Whether the op ends a region: its value is complete only after every tile.
fn is_sink<T>(op: &Op<T>) -> bool {
    matches!(op, Op::Sum | Op::ScatterAdd)
}

/// Whether the node holds given values (nothing to run).
fn is_input<T>(op: &Op<T>) -> bool {
    matches!(op, Op::Leaf | Op::Constant)
}

/// Whether two inputs read the same place.
fn same_src(a: Src, b: Src) -> bool {
    match (a, b) {
        (Src::Slot(x), Src::Slot(y)) | (Src::Array(x), Src::Array(y)) | (Src::Bcast(x), Src::Bcast(y)) => x == y,
        _ => false,
    }
}

impl<T: Real> Graph<T> {
    /// Assigns pending nodes to steps and decides which values get buffers.
    pub(super) fn plan(&mut self, start: usize, want: Option<u32>) {
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
    pub(super) fn build_region(&mut self, r: usize) {
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
}

impl<T: Real> Executor<T> {
    /// Marks, for the region's backward pass, each contribution that is the
    /// first (in reverse order) to its tile slot: it writes instead of adding.
    pub(super) fn overwrite_flags(&mut self, nodes: &[Node<T>], edges: &[u32], reg: &Region) {
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
}
