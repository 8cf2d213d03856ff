//! Scoring a visibility prediction against the truth, with "hidden" as the positive class.

use serde::Serialize;

/// Counts of a binary confusion matrix where the positive class is "hidden".
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Confusion {
    /// Predicted hidden, truly hidden.
    pub hidden_hit: u64,
    /// Predicted hidden, truly visible.
    pub false_hidden: u64,
    /// Predicted visible, truly hidden.
    pub missed_hidden: u64,
    /// Predicted visible, truly visible.
    pub visible_hit: u64,
}

impl Confusion {
    /// Adds one prediction (`true` = visible) against the truth (`true` = visible).
    pub fn add(&mut self, predicted_visible: bool, truly_visible: bool) {
        match (predicted_visible, truly_visible) {
            (false, false) => self.hidden_hit += 1,
            (false, true) => self.false_hidden += 1,
            (true, false) => self.missed_hidden += 1,
            (true, true) => self.visible_hit += 1,
        }
    }

    /// Adds a whole visibility vector against the truth.
    pub fn add_all(&mut self, predicted: &[bool], truth: &[bool]) {
        for (&p, &t) in predicted.iter().zip(truth) {
            self.add(p, t);
        }
    }

    /// Number of points scored.
    pub fn total(&self) -> u64 {
        self.hidden_hit + self.false_hidden + self.missed_hidden + self.visible_hit
    }

    /// Fraction of points classified correctly.
    pub fn accuracy(&self) -> f64 {
        ratio(self.hidden_hit + self.visible_hit, self.total())
    }

    /// Of the points called hidden, the fraction that are hidden.
    pub fn precision(&self) -> f64 {
        ratio(self.hidden_hit, self.hidden_hit + self.false_hidden)
    }

    /// Of the hidden points, the fraction called hidden.
    pub fn recall(&self) -> f64 {
        ratio(self.hidden_hit, self.hidden_hit + self.missed_hidden)
    }
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 { 1.0 } else { a as f64 / b as f64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_ratios() {
        let mut c = Confusion::default();
        c.add_all(
            &[false, false, true, true, true],
            &[false, true, false, true, true],
        );
        assert_eq!(
            (c.hidden_hit, c.false_hidden, c.missed_hidden, c.visible_hit),
            (1, 1, 1, 2)
        );
        assert_eq!(c.accuracy(), 0.6);
        assert_eq!(c.precision(), 0.5);
        assert_eq!(c.recall(), 0.5);
    }
}
