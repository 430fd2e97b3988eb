//! Errors raised when a solver is configured or started with invalid settings.

use std::fmt;

/// A setting or input that breaks a rule; names the field and the rule.
#[derive(Debug, Clone, PartialEq)]
pub enum OptimError {
    /// A setting is outside its valid range, e.g. `field: "lr"`, `rule: "must be >= 0"`.
    InvalidSetting {
        /// Which setting, e.g. `"group[1].beta2"`.
        field: String,
        /// The rule it breaks, e.g. `"must be in [0, 1)"`.
        rule: &'static str,
        /// The offending value, as written by the caller.
        value: String,
    },
    /// A vector does not have the length the solver was configured for.
    WrongLength {
        /// Which vector, e.g. `"x0"` or `"bounds.upper"`.
        field: &'static str,
        /// The length the solver expects.
        expected: usize,
        /// The length it got.
        actual: usize,
    },
    /// The objective declares itself stochastic and the solver needs exact values.
    StochasticObjective {
        /// The solver that refused, e.g. `"Lbfgs"`.
        solver: &'static str,
    },
}

impl OptimError {
    /// `Err(InvalidSetting)` unless `ok` holds, so validation reads as a list of rules.
    pub(crate) fn check(
        ok: bool,
        field: impl Into<String>,
        rule: &'static str,
        value: impl fmt::Debug,
    ) -> Result<(), Self> {
        if ok {
            Ok(())
        } else {
            Err(OptimError::InvalidSetting {
                field: field.into(),
                rule,
                value: format!("{value:?}"),
            })
        }
    }
}

impl fmt::Display for OptimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OptimError::InvalidSetting { field, rule, value } => {
                write!(f, "optim: setting `{field}` = {value} {rule}")
            }
            OptimError::WrongLength {
                field,
                expected,
                actual,
            } => write!(f, "optim: `{field}` has length {actual}, expected {expected}"),
            OptimError::StochasticObjective { solver } => write!(
                f,
                "optim: {solver} needs exact values and gradients but the objective is stochastic; use Adam"
            ),
        }
    }
}

impl std::error::Error for OptimError {}
