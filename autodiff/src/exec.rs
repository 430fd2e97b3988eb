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
//!
//! What each op computes, forward and backward, lives in its file under
//! `kernels`; the executor decides where and in which order those kernels
//! run, over the program the tape recorded (`graph`: the nodes, their kinds
//! and buffers). This file drives the steps (forward, the reverse sweep,
//! plain steps); `plan` forms the regions and their instructions; `tiles`
//! runs a region's tiles and chunks. It knows neither the tape nor the ops'
//! constructors.

mod graph;
mod plan;
mod tiles;

pub use graph::NonFinite;
pub(crate) use graph::{Graph, NONE, Node, Op, Pool};

use crate::kernels::{add_into, concat, custom, slice};
use crate::real::Real;
use plan::{Instr, Region};
use tiles::{Chunk, Pass, Ptr};

/// A unit of execution: a region of tiled nodes, or one plain node.
#[derive(Clone, Copy, Debug)]
enum Step {
    Region(u32),
    Plain(u32),
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

    /// Runs a plain node (slice, concat, custom op) over whole arrays into
    /// a new buffer.
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

    /// Adds a plain node's vector-Jacobian product into its inputs' gradients.
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
                // An input listed again (`custom(op, &[x, x])`) gets a zeroed
                // slot of its own, added into its first listing's after the op.
                let first_listing = |k: usize| (0..k).find(|&j| self.edges[first + j] == self.edges[first + k]);
                let mut again: Vec<Vec<T>> = (0..num)
                    .map(|k| match first_listing(k).and_then(|_| input_grad(&mut adj, k)) {
                        Some(g) => vec![T::zero(); g.len],
                        None => Vec::new(),
                    })
                    .collect();
                let inputs = again.iter_mut().enumerate().map(|(k, again)| {
                    let i = &self.nodes[self.edges[first + k] as usize];
                    // SAFETY: distinct inputs have distinct adjoint buffers; an
                    // input listed again writes into its own zeroed slot.
                    let g = match first_listing(k) {
                        Some(_) => (!again.is_empty()).then_some(&mut again[..]),
                        None => input_grad(&mut adj, k).map(|g| unsafe { g.slice(0, i.len as usize) }),
                    };
                    (&vals[i.value as usize][..i.len as usize], g)
                });
                let y = &vals[n.value as usize][..n.len as usize];
                custom::backward(&*self.customs[c as usize], inputs, y, gy);
                for (k, again) in again.iter().enumerate() {
                    if let (Some(j), Some(g)) = (first_listing(k), input_grad(&mut adj, k)) {
                        debug_assert!(first_listing(j).is_none());
                        // SAFETY: the op is done; `g` is the only reference to that buffer.
                        add_into(unsafe { g.slice(0, g.len) }, again);
                    }
                }
            }
            _ => unreachable!("only plain ops run as plain steps"),
        }
        adj[n.adjoint as usize] = gy_buf;
        self.adjoints.bufs = adj;
    }
}

/// The first NaN or infinity of `x`, reported as element `offset + k` of
/// node `node`'s output (or adjoint, `in_backward`), for check mode.
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
