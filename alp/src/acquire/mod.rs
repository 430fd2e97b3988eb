//! Probe acquisition, the paper's offline stage (PAPER.md, Sec. 3.2): a shiny
//! object photographed from many views under known lighting becomes a probe
//! asset. So far, its input: the capture folder ([`capture`]), which
//! `alp synth captures` renders for a known probe.

pub mod capture;
pub mod placement;
