//! The recorded program the executor plans and runs: the nodes (one per
//! array op, with its kind), their input edges, and the pools of value and
//! adjoint buffers. The tape ([`crate::Tape`]) records into it and reads
//! from it; the executor's own state lives beside it.

use std::sync::Arc;

use super::Executor;
use crate::kernels::custom::CustomOp;
use crate::kernels::map::MapKind;
use crate::real::Real;

/// Marks "none" in the node's index fields.
pub(crate) const NONE: u32 = u32::MAX;

/// What a node computes.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Op<T> {
    /// Given values, gradient wanted.
    Leaf,
    /// Given values, no gradient.
    Constant,
    /// Elementwise function of its inputs (length-1 inputs broadcast).
    Map(MapKind, [T; 2]),
    /// Sum of all elements of its input (length 1).
    Sum,
    /// out[idx[i]] += x[i]; inputs (x, idx); the node's length is the output's.
    ScatterAdd,
    /// y[i] = source[idx[i] * stride + offset]; inputs (source, idx).
    Gather { stride: u32, offset: u32 },
    /// A contiguous part of the input starting at the given element.
    Slice(u32),
    /// Inputs laid end to end.
    Concat,
    /// A user-supplied op (index into the tape's custom ops).
    Custom(u32),
}

impl<T> Op<T> {
    /// The op's name, for messages.
    pub(crate) fn name(&self) -> &'static str {
        match self {
            Op::Leaf => "leaf",
            Op::Constant => "constant",
            Op::Map(kind, _) => kind.name(),
            Op::Sum => "sum",
            Op::ScatterAdd => "scatter_add",
            Op::Gather { .. } => "gather",
            Op::Slice(_) => "slice",
            Op::Concat => "concat",
            Op::Custom(_) => "custom",
        }
    }
}

/// One array operation on the tape.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Node<T> {
    pub op: Op<T>,
    pub len: u32,
    pub first_input: u32,
    pub num_inputs: u32,
    pub requires_grad: bool,
    /// Index of the value buffer, or NONE while the value lives only in tiles.
    pub value: u32,
    /// Index of the adjoint buffer during a backward pass, or NONE.
    pub adjoint: u32,
    /// Execution step (region or plain op) once planned, or NONE.
    pub step: u32,
    /// Tile slot within its region while the value lives only in tiles.
    pub slot: u32,
    /// Planning flag: the value must be written to a buffer.
    pub materialize: bool,
    /// During a region's backward pass: the adjoint buffer holds nothing yet.
    pub fresh: bool,
    /// The tape's reset count when the node was recorded: a `Var` of an
    /// earlier count at the same index is stale.
    pub epoch: u32,
}

/// A growable set of reusable buffers: `reset` returns them all, and the next
/// requests reuse them in order, so a repeated program never reallocates.
#[derive(Default)]
pub(crate) struct Pool<T> {
    pub bufs: Vec<Vec<T>>,
    pub used: usize,
}

impl<T: Real> Pool<T> {
    /// A buffer of `len` elements with unspecified (but initialised) contents.
    pub fn take(&mut self, len: usize) -> u32 {
        if self.used == self.bufs.len() {
            self.bufs.push(Vec::new());
        }
        let b = &mut self.bufs[self.used];
        b.resize(len, T::zero());
        self.used += 1;
        (self.used - 1) as u32
    }
    /// A buffer of `len` zeros.
    pub fn take_zeroed(&mut self, len: usize) -> u32 {
        let id = self.take(len);
        self.bufs[id as usize].fill(T::zero());
        id
    }
    /// Bytes reserved by all buffers.
    pub fn reserved_bytes(&self) -> usize {
        self.bufs.iter().map(|b| b.capacity()).sum::<usize>() * std::mem::size_of::<T>()
    }
}

/// The first non-finite value found in `check_finite` mode.
#[derive(Clone, Debug, PartialEq)]
pub struct NonFinite {
    /// The node that produced it.
    pub node: usize,
    /// The op's name.
    pub op: &'static str,
    /// The element's index.
    pub index: usize,
    /// The value (NaN or an infinity).
    pub value: f64,
    /// Whether it appeared in the backward pass (an adjoint), not the forward.
    pub in_backward: bool,
}

impl std::fmt::Display for NonFinite {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "op `{}` (node {}) produced {} at element {} in the {} pass",
            self.op,
            self.node,
            self.value,
            self.index,
            if self.in_backward { "backward" } else { "forward" }
        )
    }
}

impl std::error::Error for NonFinite {}

/// Everything the tape owns; behind a `RefCell` so that recording takes `&Tape`.
pub(crate) struct Graph<T: Real> {
    pub nodes: Vec<Node<T>>,
    pub edges: Vec<u32>,
    /// Nodes below this index are planned and executed.
    pub executed: usize,
    pub values: Pool<T>,
    pub adjoints: Pool<T>,
    pub customs: Vec<Arc<dyn CustomOp<T>>>,
    pub exec: Executor<T>,
    pub check_finite: bool,
    pub non_finite: Option<NonFinite>,
    /// Number of resets so far (see `Node::epoch`).
    pub epoch: u32,
}

impl<T: Real> Graph<T> {
    /// The index of a handle's node, after checking that the node is still
    /// the one the handle was made for.
    pub(crate) fn check(&self, index: u32, epoch: u32, what: &str) -> u32 {
        match self.nodes.get(index as usize) {
            Some(n) if n.epoch == epoch => index,
            _ => panic!(
                "{what}: stale handle to node {index}: it was recorded after the mark the tape was reset to \
                 (reset_to / clear); record it again each iteration, or before the mark"
            ),
        }
    }

    /// Appends a node whose inputs are the edges from `first_input` to the end.
    pub(crate) fn push_node(&mut self, op: Op<T>, len: usize, first_input: usize, requires_grad: bool) -> u32 {
        assert!(
            len < NONE as usize,
            "{}: {len} elements exceed the tape's index range",
            op.name()
        );
        let id = self.nodes.len() as u32;
        self.nodes.push(Node {
            op,
            len: len as u32,
            first_input: first_input as u32,
            num_inputs: (self.edges.len() - first_input) as u32,
            requires_grad,
            value: NONE,
            adjoint: NONE,
            step: NONE,
            slot: NONE,
            materialize: false,
            fresh: false,
            epoch: self.epoch,
        });
        id
    }

    /// The inputs of node `id`.
    #[inline]
    pub fn inputs(&self, id: u32) -> &[u32] {
        let n = &self.nodes[id as usize];
        &self.edges[n.first_input as usize..(n.first_input + n.num_inputs) as usize]
    }
}
