//! The numerics every analysis shares: the least-squares engine ([`lsq`]), the minimax engine on
//! the same problems ([`minimax`]), forward selection of model terms by BIC ([`select`]), the
//! minimum-zone circle of a trace ([`mzc`]), and how many independent samples a correlated
//! residual is worth ([`correlation`]).
//!
//! May use: nalgebra, clarabel, the crate's error type. Knows nothing of ball bars: problems come
//! in through the [`lsq::Problem`] trait, columns and names through plain numbers and closures.
pub mod correlation;
pub mod lsq;
pub mod minimax;
pub mod mzc;
pub mod select;
