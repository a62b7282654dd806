//! What the critic is compared against: the soft Monte-Carlo return of a recorded
//! episode, and the agreement statistics of Q with it.
//!
//! Invariants: a soft return-to-go is exactly what the critic's target estimates
//! (the next state's entropy bonus counted, the step's own action's not); the
//! agreement statistics are over exactly the (Q, G) pairs given.

use serde::Serialize;

/// Soft discounted returns-to-go of one episode: Gₜ = rₜ + γ(Gₜ₊₁ − α log πₜ₊₁),
/// G_{T−1} = r_{T−1} (the next state's entropy bonus belongs to the target of the
/// critic, the first action's does not).
pub fn soft_returns(rewards: &[f32], log_probs: &[f32], gamma: f64, alpha: f64) -> Vec<f64> {
    assert_eq!(rewards.len(), log_probs.len(), "one log-probability per reward");
    let mut out = vec![0.0; rewards.len()];
    let mut next: Option<f64> = None;
    for t in (0..rewards.len()).rev() {
        let g =
            f64::from(rewards[t]) + next.map_or(0.0, |g_next| gamma * (g_next - alpha * f64::from(log_probs[t + 1])));
        out[t] = g;
        next = Some(g);
    }
    out
}

/// Q against the return over a set of steps.
#[derive(Debug, Clone, Serialize)]
pub struct ValueAgreement {
    /// Steps compared.
    pub n: usize,
    /// Mean Q(s, a).
    pub mean_q: f64,
    /// Mean Monte-Carlo soft return.
    pub mean_return: f64,
    /// Mean of Q − G (> 0: the critic overestimates).
    pub bias: f64,
    /// √mean (Q − G)².
    pub rmse: f64,
    /// Pearson correlation of Q and G.
    pub correlation: f64,
}

impl ValueAgreement {
    /// The agreement of Q with G over `pairs` of (Q, G).
    pub(super) fn of(pairs: &[(f64, f64)]) -> ValueAgreement {
        let n = pairs.len();
        let nf = n.max(1) as f64;
        let mq = pairs.iter().map(|p| p.0).sum::<f64>() / nf;
        let mg = pairs.iter().map(|p| p.1).sum::<f64>() / nf;
        let cov = pairs.iter().map(|p| (p.0 - mq) * (p.1 - mg)).sum::<f64>();
        let vq = pairs.iter().map(|p| (p.0 - mq).powi(2)).sum::<f64>();
        let vg = pairs.iter().map(|p| (p.1 - mg).powi(2)).sum::<f64>();
        ValueAgreement {
            n,
            mean_q: mq,
            mean_return: mg,
            bias: mq - mg,
            rmse: (pairs.iter().map(|p| (p.0 - p.1).powi(2)).sum::<f64>() / nf).sqrt(),
            correlation: cov / (vq * vg).sqrt(),
        }
    }
}
