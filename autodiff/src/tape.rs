//! The tape: an arena of array-valued nodes indexed by integers.
//!
//! Recording an op only appends a node; values are computed lazily, when a
//! value or a gradient is asked for, so that the executor sees whole chains of
//! elementwise ops and can run them tile by tile (see `exec`). `clear` keeps
//! every buffer, so an iteration that records the same program again
//! allocates nothing.

use std::cell::{Ref, RefCell};
use std::sync::Arc;

use crate::ops::custom::CustomOp;
use crate::ops::map::MapKind;
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
    pub exec: crate::exec::Executor<T>,
    pub check_finite: bool,
    pub non_finite: Option<NonFinite>,
    /// Number of resets so far (see `Node::epoch`).
    pub epoch: u32,
}

/// A position on the tape to return to with [`Tape::reset_to`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mark {
    nodes: usize,
    edges: usize,
    values: usize,
    customs: usize,
}

/// A tape of array operations for reverse-mode differentiation.
///
/// ```
/// use autodiff::Tape;
/// let tape = Tape::<f64>::new();
/// let x = tape.leaf(&[1.0, 2.0, 3.0]);
/// let y = (x * x + 1.0).sqrt().sum();
/// tape.backward(y);
/// assert!((tape.value(y)[0] - (2f64.sqrt() + 5f64.sqrt() + 10f64.sqrt())).abs() < 1e-12);
/// assert!((tape.grad(x)[1] - 2.0 / 5f64.sqrt()).abs() < 1e-12);
/// ```
pub struct Tape<T: Real> {
    pub(crate) graph: RefCell<Graph<T>>,
}

/// Handle to a node of a tape: an array of `len` elements.
#[derive(Clone, Copy)]
pub struct Var<'t, T: Real> {
    pub(crate) tape: &'t Tape<T>,
    index: u32,
    epoch: u32,
}

/// A node's index, without the borrow of the tape (to keep leaves across iterations).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VarId {
    index: u32,
    epoch: u32,
}

impl<T: Real> Default for Tape<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Real> Tape<T> {
    /// An empty tape.
    pub fn new() -> Self {
        Tape {
            graph: RefCell::new(Graph {
                nodes: Vec::new(),
                edges: Vec::new(),
                executed: 0,
                values: Pool {
                    bufs: Vec::new(),
                    used: 0,
                },
                adjoints: Pool {
                    bufs: Vec::new(),
                    used: 0,
                },
                customs: Vec::new(),
                exec: Default::default(),
                check_finite: false,
                non_finite: None,
                epoch: 0,
            }),
        }
    }

    /// Removes every node but keeps every buffer for the next iteration
    /// (handles recorded before become stale).
    pub fn clear(&self) {
        self.reset_to(Mark {
            nodes: 0,
            edges: 0,
            values: 0,
            customs: 0,
        });
    }

    /// The current end of the tape: record static inputs (meshes, textures,
    /// parameters) once, take a mark, and `reset_to` it every iteration.
    pub fn mark(&self) -> Mark {
        let mut g = self.graph.borrow_mut();
        g.execute(None);
        // Nodes before a mark outlive resets: give each computed value a
        // buffer below the mark now, so none is rematerialised above it later.
        for id in 0..g.nodes.len() as u32 {
            if g.nodes[id as usize].value == NONE {
                g.rematerialize(id);
            }
        }
        Mark {
            nodes: g.nodes.len(),
            edges: g.edges.len(),
            values: g.values.used,
            customs: g.customs.len(),
        }
    }

    /// Drops every node recorded after `mark`, keeping the buffers. Handles
    /// to nodes before the mark stay valid; using a handle to a dropped node
    /// panics (it is stale, not silently another node).
    pub fn reset_to(&self, mark: Mark) {
        let mut g = self.graph_mut("reset_to");
        let g = &mut *g;
        g.epoch += 1;
        assert!(
            mark.nodes <= g.nodes.len(),
            "reset_to: the mark is beyond the tape's end"
        );
        g.nodes.truncate(mark.nodes);
        g.edges.truncate(mark.edges);
        g.customs.truncate(mark.customs);
        g.values.used = mark.values;
        g.executed = g.executed.min(mark.nodes);
        g.exec.truncate(mark.nodes as u32, &mut g.nodes);
        g.adjoints.used = 0;
        for n in &mut g.nodes {
            n.adjoint = NONE;
        }
        g.non_finite = None;
    }

    /// A leaf: an array whose gradient [`backward`](Self::backward) computes.
    pub fn leaf(&self, values: &[T]) -> Var<'_, T> {
        self.input(values, Op::Leaf)
    }

    /// A constant array (no gradient).
    pub fn constant(&self, values: &[T]) -> Var<'_, T> {
        self.input(values, Op::Constant)
    }

    /// A constant scalar (a length-1 array, which broadcasts).
    pub fn scalar(&self, value: T) -> Var<'_, T> {
        self.input(&[value], Op::Constant)
    }

    fn input(&self, values: &[T], op: Op<T>) -> Var<'_, T> {
        assert!(!values.is_empty(), "{}: an array needs at least one element", op.name());
        let mut g = self.graph_mut(op.name());
        let buf = g.values.take(values.len());
        g.values.bufs[buf as usize].copy_from_slice(values);
        let first = g.edges.len();
        let id = g.push_node(op, values.len(), first, matches!(op, Op::Leaf));
        g.nodes[id as usize].value = buf;
        // Inputs need no execution: keep them out of the planner's way.
        if g.executed == id as usize {
            g.executed += 1;
        }
        Var {
            tape: self,
            index: id,
            epoch: g.epoch,
        }
    }

    /// Replaces a leaf's or constant's values (same length), e.g. the
    /// parameters of the next iteration after [`reset_to`](Self::reset_to).
    ///
    /// Panics if a computed node already follows it on the tape: its value
    /// would be stale.
    pub fn set_values(&self, var: VarId, values: &[T]) {
        let mut g = self.graph_mut("set_values");
        let id = g.check(var.index, var.epoch, "set_values");
        let node = g.nodes[id as usize];
        assert!(
            matches!(node.op, Op::Leaf | Op::Constant),
            "set_values: node {} is a computed `{}`, not an input",
            id,
            node.op.name()
        );
        assert_eq!(
            values.len(),
            node.len as usize,
            "set_values: node {} has {} elements, got {}",
            id,
            node.len,
            values.len()
        );
        let later_computed = g.nodes[id as usize..]
            .iter()
            .any(|n| !matches!(n.op, Op::Leaf | Op::Constant));
        assert!(
            !later_computed,
            "set_values: computed nodes follow node {} on the tape; reset_to a mark first",
            id
        );
        g.values.bufs[node.value as usize].copy_from_slice(values);
    }

    /// Re-wraps a node index as a handle (panics if the node was dropped by a reset).
    pub fn var(&self, id: VarId) -> Var<'_, T> {
        self.graph.borrow().check(id.index, id.epoch, "var");
        Var {
            tape: self,
            index: id.index,
            epoch: id.epoch,
        }
    }

    /// The node's values (computed now if pending).
    ///
    /// The returned guard borrows the tape: copy what you need (`to_vec`, `[0]`)
    /// before recording or computing more.
    pub fn value(&self, var: Var<'_, T>) -> Ref<'_, [T]> {
        let id = var.node();
        let ready = {
            let g = self.graph.borrow();
            (id as usize) < g.executed && g.nodes[id as usize].value != NONE
        };
        if !ready {
            self.graph_mut("value").execute(Some(id));
        }
        Ref::map(self.graph.borrow(), |g| {
            let n = &g.nodes[id as usize];
            &g.values.bufs[n.value as usize][..n.len as usize]
        })
    }

    /// The node's values, copied out (no guard: usable anywhere in an expression).
    pub fn to_vec(&self, var: Var<'_, T>) -> Vec<T> {
        self.value(var).to_vec()
    }

    /// The first value of a node (a scalar's value).
    pub fn item(&self, var: Var<'_, T>) -> T {
        self.value(var)[0]
    }

    /// Gradient of the last [`backward`](Self::backward)'s output with
    /// respect to `var`: every leaf has one (zeros where the output does not
    /// depend on it); a computed node has one if it was kept in a buffer.
    pub fn grad(&self, var: Var<'_, T>) -> Ref<'_, [T]> {
        let id = var.node();
        let g = self.graph.borrow();
        let n = &g.nodes[id as usize];
        assert!(
            n.adjoint != NONE,
            "grad: node {} (`{}`) has no gradient: call backward first; gradients of \
             intermediate values are not kept unless they are read elsewhere (make it a leaf)",
            id,
            n.op.name()
        );
        Ref::map(g, |g| {
            let n = &g.nodes[id as usize];
            &g.adjoints.bufs[n.adjoint as usize][..n.len as usize]
        })
    }

    /// Mutable access to the graph, with a clear message when a value or
    /// gradient guard is still alive.
    fn graph_mut(&self, what: &str) -> std::cell::RefMut<'_, Graph<T>> {
        self.graph.try_borrow_mut().unwrap_or_else(|_| {
            panic!(
                "{what}: the tape is borrowed by a value or gradient still in use; \
                 copy what you need (`.to_vec()`, `[i]`) before computing more"
            )
        })
    }

    /// Reverse sweep from a length-1 `output`: fills the gradient of every
    /// node that needs one. Each call starts afresh, so several backward
    /// passes after one forward give the gradients of several outputs.
    pub fn backward(&self, output: Var<'_, T>) {
        let id = output.node();
        let mut g = self.graph_mut("backward");
        let len = g.nodes[id as usize].len;
        assert_eq!(len, 1, "backward: the output must have one element, it has {len}");
        g.backward(id);
    }

    /// In check mode, every op's output (and every adjoint) is scanned and
    /// the first non-finite value is reported by [`non_finite`](Self::non_finite).
    pub fn set_check_finite(&self, on: bool) {
        self.graph.borrow_mut().check_finite = on;
    }

    /// The first NaN or infinity found in check mode, naming the op.
    pub fn non_finite(&self) -> Option<NonFinite> {
        let mut g = self.graph.borrow_mut();
        g.execute(None);
        g.non_finite.clone()
    }

    /// Number of nodes on the tape.
    pub fn len(&self) -> usize {
        self.graph.borrow().nodes.len()
    }

    /// Whether the tape has no nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes reserved by all buffers (values, adjoints, tiles): flat from one
    /// iteration to the next once the program repeats.
    pub fn reserved_bytes(&self) -> usize {
        let g = self.graph.borrow();
        g.values.reserved_bytes() + g.adjoints.reserved_bytes() + g.exec.reserved_bytes()
    }

    /// Records a node; shapes are checked by the caller.
    pub(crate) fn record<'a>(&'a self, op: Op<T>, len: usize, inputs: &[Var<'a, T>]) -> Var<'a, T> {
        self.record_iter(op, len, inputs.iter().copied())
    }

    /// [`record`](Self::record) for inputs given by an iterator (no
    /// temporary list to allocate).
    pub(crate) fn record_iter<'a>(
        &'a self,
        op: Op<T>,
        len: usize,
        inputs: impl Iterator<Item = Var<'a, T>>,
    ) -> Var<'a, T> {
        self.push_computed(op, len, inputs, true)
    }

    /// Records a node whose gradient is cut (stop_gradient).
    pub(crate) fn record_detached<'a>(&'a self, op: Op<T>, len: usize, inputs: &[Var<'a, T>]) -> Var<'a, T> {
        self.push_computed(op, len, inputs.iter().copied(), false)
    }

    fn push_computed<'a>(
        &'a self,
        op: Op<T>,
        len: usize,
        inputs: impl Iterator<Item = Var<'a, T>>,
        gradients: bool,
    ) -> Var<'a, T> {
        let mut g = self.graph_mut(op.name());
        let differentiable = gradients
            && match op {
                Op::Map(kind, _) => kind.differentiable(),
                Op::Constant => false,
                _ => true,
            };
        let first = g.edges.len();
        for v in inputs {
            assert!(
                std::ptr::eq(v.tape, self),
                "{}: operands live on different tapes",
                op.name()
            );
            let id = g.check(v.index, v.epoch, op.name());
            g.edges.push(id);
        }
        let requires_grad = differentiable && g.edges[first..].iter().any(|&i| g.nodes[i as usize].requires_grad);
        let id = g.push_node(op, len, first, requires_grad);
        Var {
            tape: self,
            index: id,
            epoch: g.epoch,
        }
    }
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
    fn push_node(&mut self, op: Op<T>, len: usize, first_input: usize, requires_grad: bool) -> u32 {
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

impl<'t, T: Real> Var<'t, T> {
    /// Number of elements.
    pub fn len(self) -> usize {
        let id = self.node();
        self.tape.graph.borrow().nodes[id as usize].len as usize
    }

    /// Whether the array is empty (never: arrays have at least one element).
    pub fn is_empty(self) -> bool {
        self.len() == 0
    }

    /// The node's index, to keep across iterations (see [`Tape::var`]).
    pub fn id(self) -> VarId {
        VarId {
            index: self.node(),
            epoch: self.epoch,
        }
    }

    /// The node's index, checked to be current.
    pub(crate) fn node(self) -> u32 {
        self.tape.graph.borrow().check(self.index, self.epoch, "handle")
    }

    /// The tape this node lives on.
    pub fn tape(self) -> &'t Tape<T> {
        self.tape
    }

    /// Whether gradients flow into this node.
    pub fn requires_grad(self) -> bool {
        let id = self.node();
        self.tape.graph.borrow().nodes[id as usize].requires_grad
    }

    pub(crate) fn same_tape(self, other: Var<'_, T>, op: &str) {
        assert!(
            std::ptr::eq(self.tape, other.tape),
            "{op}: operands live on different tapes"
        );
    }
}

impl<T: Real> std::fmt::Debug for Var<'_, T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let g = self.tape.graph.borrow();
        match g.nodes.get(self.index as usize) {
            Some(n) if n.epoch == self.epoch => write!(f, "Var(#{} {} [{}])", self.index, n.op.name(), n.len),
            _ => write!(f, "Var(#{} stale)", self.index),
        }
    }
}
