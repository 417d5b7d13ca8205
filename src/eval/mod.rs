//! Evaluation with the thesis' metrics: location and heading errors of the folded prediction
//! (oracle), of the heaviest hypothesis (modelled) and of the closest hypothesis (best of set), the
//! fold-bit error, errors by distance to the fold boundary, and accuracy against coverage.

mod metrics;
mod truth;
mod twins;

pub(crate) use metrics::median;
pub use metrics::{
    BurstEvaluation, BurstMetrics, Coverage, ErrorStats, Evaluation, Metrics, RefinedEvaluation,
    RefinedMetrics, Sample,
};
pub use truth::{TruthEvaluation, TruthMetrics};
pub use twins::{TwinEvaluation, TwinMetrics};
