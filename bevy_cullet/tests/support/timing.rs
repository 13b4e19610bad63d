//! Timer systems and means for the plugin's benches: each `mark` system records when it ran, ordered around
//! the systems a bench times.

#![allow(dead_code)]

use bevy_ecs::prelude::*;
use std::time::{Duration, Instant};

/// The instants a frame's `N` timer systems record.
#[derive(Resource)]
pub struct Marks<const N: usize>(pub [Option<Instant>; N]);

impl<const N: usize> Default for Marks<N> {
    fn default() -> Self {
        Self([None; N])
    }
}

impl<const N: usize> Marks<N> {
    /// Every mark of the frame.
    ///
    /// # Panics
    /// Where a timer system did not run.
    pub fn all(&self) -> [Instant; N] {
        self.0.map(|mark| mark.expect("every timer ran"))
    }
}

/// Timer system `I` of `N`.
pub fn mark<const N: usize, const I: usize>(mut marks: ResMut<Marks<N>>) {
    marks.0[I] = Some(Instant::now());
}

/// The mean of `times`, in milliseconds.
pub fn mean_ms(times: &[Duration]) -> f64 {
    times.iter().map(Duration::as_secs_f64).sum::<f64>() * 1e3 / times.len() as f64
}

/// The median of `times`, in milliseconds.
pub fn median_ms(times: &[Duration]) -> f64 {
    let mut sorted = times.to_vec();
    sorted.sort_unstable();
    sorted[sorted.len() / 2].as_secs_f64() * 1e3
}
