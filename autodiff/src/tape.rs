//! The tape: an arena of array-valued nodes indexed by integers.
//!
//! Recording an op only appends a node; values are computed lazily, when a
//! value or a gradient is asked for, so that the executor sees whole chains of
//! elementwise ops and can run them tile by tile (see `exec`). `clear` keeps
//! every buffer, so an iteration that records the same program again
//! allocates nothing.

use std::cell::{Ref, RefCell};

use crate::exec::{Graph, NONE, NonFinite, Op, Pool};
use crate::real::Real;

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
