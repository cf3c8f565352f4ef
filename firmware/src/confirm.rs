//! Confirmation: a mark must be seen in K of the last N frames before the robot moves.
//!
//! Defaults: [`DEFAULT_K`] = 3 of [`DEFAULT_N`] = 5. One or two noisy frames never make it reach,
//! and a mark lost for a frame or two (a blink of the eye LEDs, a dropped frame) still confirms.
//! The window starts empty, so the earliest reach is on the K-th frame with a mark.

/// Frames with a mark needed.
pub const DEFAULT_K: u8 = 3;
/// Window length in frames.
pub const DEFAULT_N: u8 = 5;
/// Longest window.
pub const MAX_N: u8 = 32;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// The K-of-N confirmation filter: a bit per frame of the last N, mark or not.
pub struct Confirm {
    k: u8,
    n: u8,
    /// Bit i: frame i back had a mark.
    history: u32,
}

impl Default for Confirm {
    fn default() -> Self {
        Confirm::defaults()
    }
}

impl Confirm {
    /// [`DEFAULT_K`] of [`DEFAULT_N`].
    pub const fn defaults() -> Self {
        Confirm {
            k: DEFAULT_K,
            n: DEFAULT_N,
            history: 0,
        }
    }

    /// `None` unless `1 <= k <= n <= MAX_N`.
    pub const fn new(k: u8, n: u8) -> Option<Self> {
        if k == 0 || k > n || n > MAX_N {
            None
        } else {
            Some(Confirm { k, n, history: 0 })
        }
    }

    /// Marks needed in the window (K).
    pub fn k(&self) -> u8 {
        self.k
    }

    /// Window length in frames (N).
    pub fn n(&self) -> u8 {
        self.n
    }

    /// Records one frame; true when at least K of the last N had a mark.
    pub fn push(&mut self, mark: bool) -> bool {
        let keep = if self.n >= 32 {
            u32::MAX
        } else {
            (1u32 << self.n) - 1
        };
        self.history = ((self.history << 1) | mark as u32) & keep;
        self.history.count_ones() >= self.k as u32
    }

    /// No frame of the window had a mark: no candidate is being confirmed.
    pub fn quiet(&self) -> bool {
        self.history == 0
    }

    /// Forgets the window (after a reach, so the old mark does not trigger another at once).
    pub fn reset(&mut self) {
        self.history = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn k_of_n() {
        let mut c = Confirm::default();
        assert_eq!((c.k(), c.n()), (3, 5));
        // A single noisy frame, then nothing: never.
        assert!(!c.push(true));
        for _ in 0..10 {
            assert!(!c.push(false));
        }
        // Two marks, a miss, a third: confirms on the third.
        assert!(!c.push(true));
        assert!(!c.push(true));
        assert!(!c.push(false));
        assert!(c.push(true));
        c.reset();
        assert!(!c.push(true));
        // Marks spread wider than N do not add up.
        let mut c = Confirm::new(2, 3).unwrap();
        for m in [true, false, false, true, false, false, true] {
            assert!(!c.push(m));
        }
        assert!(Confirm::new(0, 3).is_none());
        assert!(Confirm::new(4, 3).is_none());
        assert!(Confirm::new(3, 33).is_none());
        let mut c = Confirm::new(32, 32).unwrap();
        for i in 0..32 {
            assert_eq!(c.push(true), i == 31);
        }
    }
}
