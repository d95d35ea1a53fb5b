//! Ring-buffer experience replay with compile-time capacity.
//!
//! Stored column-wise (one array per field) so a batch gather reads contiguous rows. Each
//! transition carries the id of its episode, so fixed-length sequences for Retrace are drawn
//! only from consecutive transitions of one episode.
//!
//! **Interleaved episodes.** A fleet of plants inserts the blocks of several episodes in turn
//! ([`Replay::push_to`] with one episode id per plant's episode): then the transition after
//! another of the same episode is not necessarily in the next slot. With
//! [`Replay::set_interleave`] the n-step fold looks up to that many slots past each
//! transition for the next one of its episode, skipping the others; 0 (the default, one
//! plant) is the contiguous fold, bit for bit.

use bytemuck::Zeroable;

use crate::batch::BatchChunk;
use crate::rng::Rng;

/// The longest n-step transition [`Replay::fill_batch`] folds.
pub const MAX_NSTEP: usize = 64;

/// How [`Replay::fill_batch`] builds the rows of a batch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BatchMode {
    /// Single transitions, each folded over up to `n` steps of its episode (`n = 1`: TD(0)).
    OneStep {
        /// Steps per transition.
        n: u32,
        /// Discount factor.
        gamma: f32,
    },
    /// `len` consecutive transitions of one episode per row (Retrace).
    Sequences {
        /// Transitions per row.
        len: u32,
        /// Discount factor.
        gamma: f32,
    },
}

/// One transition, as inserted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transition<const OBS: usize, const ACT: usize> {
    /// State.
    pub obs: [f32; OBS],
    /// Action taken (as sampled, before any clipping by the plant).
    pub action: [f32; ACT],
    /// Reward received.
    pub reward: f32,
    /// Next state.
    pub next_obs: [f32; OBS],
    /// Discount to the next state: 0 at a true terminal, 1 otherwise (a time-limit
    /// truncation is not a terminal and keeps 1).
    pub discount: f32,
    /// `ln b(a | s)` of the behaviour policy that chose the action (for Retrace).
    pub behaviour_log_prob: f32,
}

/// Replay memory for up to `CAP` transitions; the oldest is overwritten when full.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Replay<const CAP: usize, const OBS: usize, const ACT: usize> {
    obs: [[f32; OBS]; CAP],
    action: [[f32; ACT]; CAP],
    next_obs: [[f32; OBS]; CAP],
    reward: [f32; CAP],
    discount: [f32; CAP],
    behaviour_log_prob: [f32; CAP],
    episode: [u64; CAP],
    /// Slot the next insertion writes.
    head: u64,
    /// Number of valid transitions.
    len: u64,
    /// Transitions ever inserted.
    inserted: u64,
    /// Id of the current episode.
    current_episode: u64,
    /// Slots the n-step fold may skip between two transitions of one episode (0: contiguous).
    interleave: u64,
}

/// The ring's bookkeeping (see [`Replay::raw`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReplayCounters {
    /// Slot the next insertion writes.
    pub head: u64,
    /// Number of valid transitions.
    pub len: u64,
    /// Transitions ever inserted.
    pub inserted: u64,
    /// Id of the current episode.
    pub current_episode: u64,
}

/// Counters that no sequence of insertions could produce.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InvalidCounters;

impl core::fmt::Display for InvalidCounters {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("inconsistent replay counters")
    }
}

impl core::error::Error for InvalidCounters {}

/// Borrowed columns of a [`Replay`] in slot order, with its counters.
pub struct RawReplay<'a, const CAP: usize, const OBS: usize, const ACT: usize> {
    /// States.
    pub obs: &'a [[f32; OBS]; CAP],
    /// Actions.
    pub action: &'a [[f32; ACT]; CAP],
    /// Next states.
    pub next_obs: &'a [[f32; OBS]; CAP],
    /// Rewards.
    pub reward: &'a [f32; CAP],
    /// Discounts.
    pub discount: &'a [f32; CAP],
    /// Behaviour log-probabilities.
    pub behaviour_log_prob: &'a [f32; CAP],
    /// Episode ids.
    pub episode: &'a [u64; CAP],
    /// Ring counters.
    pub counters: ReplayCounters,
}

/// Mutable columns of a [`Replay`] in slot order.
pub struct RawReplayMut<'a, const CAP: usize, const OBS: usize, const ACT: usize> {
    /// States.
    pub obs: &'a mut [[f32; OBS]; CAP],
    /// Actions.
    pub action: &'a mut [[f32; ACT]; CAP],
    /// Next states.
    pub next_obs: &'a mut [[f32; OBS]; CAP],
    /// Rewards.
    pub reward: &'a mut [f32; CAP],
    /// Discounts.
    pub discount: &'a mut [f32; CAP],
    /// Behaviour log-probabilities.
    pub behaviour_log_prob: &'a mut [f32; CAP],
    /// Episode ids.
    pub episode: &'a mut [u64; CAP],
}

/// Why a sequence could not be drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SampleError {
    /// Fewer stored transitions than asked for.
    NotEnoughData,
    /// No run of consecutive transitions of one episode is long enough (after a bounded
    /// number of tries, so sampling time stays bounded).
    NoSequence,
}

impl core::fmt::Display for SampleError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NotEnoughData => f.write_str("replay holds too few transitions"),
            Self::NoSequence => f.write_str("no single-episode sequence of that length found"),
        }
    }
}

impl core::error::Error for SampleError {}

impl<const CAP: usize, const OBS: usize, const ACT: usize> Replay<CAP, OBS, ACT> {
    /// Resets to empty (the storage is reused; nothing is freed or allocated).
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
        self.inserted = 0;
        self.current_episode = 0;
    }

    /// Number of stored transitions.
    pub fn len(&self) -> usize {
        self.len as usize
    }

    /// True when nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Capacity.
    pub const fn capacity(&self) -> usize {
        CAP
    }

    /// Transitions inserted since construction (including overwritten ones).
    pub fn inserted(&self) -> u64 {
        self.inserted
    }

    /// Marks the start of a new episode: later transitions never join a sequence with earlier
    /// ones.
    pub fn begin_episode(&mut self) {
        self.current_episode += 1;
    }

    /// Appends a transition to the current episode.
    pub fn push(&mut self, t: &Transition<OBS, ACT>) {
        self.push_to(self.current_episode, t);
    }

    /// A fresh episode id for [`Replay::push_to`] (the counter [`Replay::begin_episode`]
    /// advances, so ids never repeat within the ring, whichever way they are drawn).
    pub fn new_episode_id(&mut self) -> u64 {
        self.current_episode += 1;
        self.current_episode
    }

    /// How many slots of other episodes the n-step fold may skip between two transitions of
    /// one episode: 0 for one stream of episodes (contiguous), about `(plants - 1) * block`
    /// for a fleet whose plants insert blocks of `block` transitions in turn. A transition
    /// whose successor lies further away folds fewer steps (a valid, shorter target).
    pub fn set_interleave(&mut self, slots: u64) {
        self.interleave = slots;
    }

    /// Appends a transition to the episode `episode` (an id from [`Replay::new_episode_id`]):
    /// for several episodes inserted in turn.
    pub fn push_to(&mut self, episode: u64, t: &Transition<OBS, ACT>) {
        let i = self.head as usize;
        self.obs[i] = t.obs;
        self.action[i] = t.action;
        self.next_obs[i] = t.next_obs;
        self.reward[i] = t.reward;
        self.discount[i] = t.discount;
        self.behaviour_log_prob[i] = t.behaviour_log_prob;
        self.episode[i] = episode;
        self.head = (self.head + 1) % CAP as u64;
        self.len = (self.len + 1).min(CAP as u64);
        self.inserted += 1;
    }

    /// Slot of the `k`-th oldest stored transition.
    fn slot(&self, k: usize) -> usize {
        (self.head as usize + CAP - self.len as usize + k) % CAP
    }

    /// The `k`-th oldest stored transition.
    pub fn get(&self, k: usize) -> Transition<OBS, ACT> {
        assert!(
            k < self.len(),
            "replay index {k} out of {} stored",
            self.len
        );
        let i = self.slot(k);
        Transition {
            obs: self.obs[i],
            action: self.action[i],
            reward: self.reward[i],
            next_obs: self.next_obs[i],
            discount: self.discount[i],
            behaviour_log_prob: self.behaviour_log_prob[i],
        }
    }

    /// Draws the start (age index) of a sequence of `len` consecutive transitions of one
    /// episode, uniformly over the valid starts (rejection sampling, at most 1000 tries).
    pub fn sample_sequence_start(&self, rng: &mut Rng, len: usize) -> Result<usize, SampleError> {
        if len == 0 || self.len() < len {
            return Err(SampleError::NotEnoughData);
        }
        let starts = (self.len() - len + 1) as u64;
        for _ in 0..1000 {
            let k = rng.below(starts) as usize;
            if self.episode[self.slot(k)] == self.episode[self.slot(k + len - 1)] {
                return Ok(k);
            }
        }
        Err(SampleError::NoSequence)
    }

    /// Fills every row of a learner's batch (`chunks`, rows in chunk order) with uniformly
    /// drawn experience, as `mode` asks:
    /// - [`BatchMode::OneStep`]: a transition drawn uniformly, folded with the up to `n - 1`
    ///   transitions that follow it in its episode ([`crate::evaluation::nstep`]; fewer at
    ///   the end of an episode or of the stored data) into position 0: its state and action,
    ///   the discounted reward sum, the last next state and `gamma^k` times the discounts;
    /// - [`BatchMode::Sequences`]: `len` consecutive transitions of one episode
    ///   ([`Replay::sample_sequence_start`]) at positions `0..len`, each with
    ///   `bootstrap = gamma * discount`.
    pub fn fill_batch<const BC: usize, const L: usize>(
        &self,
        rng: &mut Rng,
        chunks: &mut [BatchChunk<BC, L, OBS, ACT>],
        mode: BatchMode,
    ) -> Result<(), SampleError> {
        if self.is_empty() {
            return Err(SampleError::NotEnoughData);
        }
        for chunk in chunks.iter_mut() {
            for n in 0..BC {
                match mode {
                    BatchMode::OneStep { n: steps, gamma } => {
                        let k = rng.below(self.len) as usize;
                        self.fold(k, steps.max(1) as usize, gamma, chunk, n);
                    }
                    BatchMode::Sequences { len, gamma } => {
                        let len = len as usize;
                        assert!(len <= L, "sequence length {len} exceeds the batch's {L}");
                        let k0 = self.sample_sequence_start(rng, len)?;
                        for k in 0..len {
                            let i = self.slot(k0 + k);
                            chunk.obs[k][n] = self.obs[i];
                            chunk.action[k][n] = self.action[i];
                            chunk.reward[k][n] = self.reward[i];
                            chunk.next_obs[k][n] = self.next_obs[i];
                            chunk.bootstrap[k][n] = gamma * self.discount[i];
                            chunk.behaviour_log_prob[k][n] = self.behaviour_log_prob[i];
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// Position 0 of row `n` of `chunk`: the `steps`-step transition starting at age index `k`.
    fn fold<const BC: usize, const L: usize>(
        &self,
        k: usize,
        steps: usize,
        gamma: f32,
        chunk: &mut BatchChunk<BC, L, OBS, ACT>,
        n: usize,
    ) {
        let first = self.slot(k);
        let mut rewards = [0f32; MAX_NSTEP];
        let mut discounts = [0f32; MAX_NSTEP];
        let mut m = 0;
        let mut last = first;
        if self.interleave == 0 {
            while m < steps.min(MAX_NSTEP) && k + m < self.len() {
                let i = self.slot(k + m);
                if self.episode[i] != self.episode[first] {
                    break;
                }
                rewards[m] = self.reward[i];
                discounts[m] = self.discount[i];
                last = i;
                m += 1;
            }
        } else {
            // The episode's transitions in insertion order, others' skipped: at most
            // `interleave` foreign slots between two of them.
            let (mut j, mut gap) = (k, 0u64);
            while m < steps.min(MAX_NSTEP) && j < self.len() && gap <= self.interleave {
                let i = self.slot(j);
                if self.episode[i] == self.episode[first] {
                    rewards[m] = self.reward[i];
                    discounts[m] = self.discount[i];
                    last = i;
                    m += 1;
                    gap = 0;
                } else {
                    gap += 1;
                }
                j += 1;
            }
        }
        let (r, b) = crate::evaluation::nstep(&rewards[..m], &discounts[..m], gamma);
        chunk.obs[0][n] = self.obs[first];
        chunk.action[0][n] = self.action[first];
        chunk.reward[0][n] = r;
        chunk.next_obs[0][n] = self.next_obs[last];
        chunk.bootstrap[0][n] = b;
        chunk.behaviour_log_prob[0][n] = self.behaviour_log_prob[first];
    }

    /// Every stored column in slot order (not age order) with the ring's counters: what a
    /// host checkpoint must save to restore the buffer bit for bit.
    pub fn raw(&self) -> RawReplay<'_, CAP, OBS, ACT> {
        RawReplay {
            obs: &self.obs,
            action: &self.action,
            next_obs: &self.next_obs,
            reward: &self.reward,
            discount: &self.discount,
            behaviour_log_prob: &self.behaviour_log_prob,
            episode: &self.episode,
            counters: self.counters(),
        }
    }

    /// The ring's counters.
    pub fn counters(&self) -> ReplayCounters {
        ReplayCounters {
            head: self.head,
            len: self.len,
            inserted: self.inserted,
            current_episode: self.current_episode,
        }
    }

    /// Mutable columns in slot order (to restore a checkpoint; pair with
    /// [`Replay::set_counters`]).
    pub fn raw_columns_mut(&mut self) -> RawReplayMut<'_, CAP, OBS, ACT> {
        RawReplayMut {
            obs: &mut self.obs,
            action: &mut self.action,
            next_obs: &mut self.next_obs,
            reward: &mut self.reward,
            discount: &mut self.discount,
            behaviour_log_prob: &mut self.behaviour_log_prob,
            episode: &mut self.episode,
        }
    }

    /// Restores the counters; rejects values no sequence of pushes could produce
    /// (`head >= CAP`, `len > CAP`, `len > inserted`, or a non-full ring whose head is not
    /// its length).
    pub fn set_counters(&mut self, c: ReplayCounters) -> Result<(), InvalidCounters> {
        let cap = CAP as u64;
        let full = c.len == cap;
        if c.head >= cap || c.len > cap || c.len > c.inserted || (!full && c.head != c.len) {
            return Err(InvalidCounters);
        }
        self.head = c.head;
        self.len = c.len;
        self.inserted = c.inserted;
        self.current_episode = c.current_episode;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::boxed::Box;

    fn t(x: f32) -> Transition<2, 1> {
        Transition {
            obs: [x, -x],
            action: [x * 0.5],
            reward: x,
            next_obs: [x + 1.0, -x - 1.0],
            discount: 1.0,
            behaviour_log_prob: -x,
        }
    }

    #[test]
    fn ring_overwrites_the_oldest() {
        let mut r: Box<Replay<4, 2, 1>> = bytemuck::zeroed_box();
        r.begin_episode();
        for i in 0..6 {
            r.push(&t(i as f32));
        }
        assert_eq!(r.len(), 4);
        assert_eq!(r.inserted(), 6);
        for k in 0..4 {
            assert_eq!(r.get(k), t((k + 2) as f32));
        }
    }

    #[test]
    fn sequences_stay_inside_one_episode() {
        let mut r: Box<Replay<64, 2, 1>> = bytemuck::zeroed_box();
        let mut x = 0.0;
        for ep_len in [3, 10, 2, 7] {
            r.begin_episode();
            for _ in 0..ep_len {
                r.push(&t(x));
                x += 1.0;
            }
        }
        let mut rng = Rng::seed_from_u64(1);
        for _ in 0..200 {
            let k = r.sample_sequence_start(&mut rng, 5).unwrap();
            // Episodes hold rewards [0,3), [3,13), [13,15), [15,22): a valid 5-sequence starts
            // inside the 10-step or the 7-step episode.
            let first = r.get(k).reward as usize;
            assert!(
                (3..=8).contains(&first) || (15..=17).contains(&first),
                "start {first}"
            );
        }
        assert_eq!(
            r.sample_sequence_start(&mut rng, 11),
            Err(SampleError::NoSequence)
        );
    }

    #[test]
    fn raw_columns_and_counters_restore_a_copy() {
        let mut r: Box<Replay<4, 2, 1>> = bytemuck::zeroed_box();
        r.begin_episode();
        for i in 0..6 {
            r.push(&t(i as f32));
        }
        let mut c: Box<Replay<4, 2, 1>> = bytemuck::zeroed_box();
        let src = r.raw();
        let dst = c.raw_columns_mut();
        *dst.obs = *src.obs;
        *dst.action = *src.action;
        *dst.next_obs = *src.next_obs;
        *dst.reward = *src.reward;
        *dst.discount = *src.discount;
        *dst.behaviour_log_prob = *src.behaviour_log_prob;
        *dst.episode = *src.episode;
        c.set_counters(src.counters).unwrap();
        for k in 0..4 {
            assert_eq!(c.get(k), r.get(k));
        }
        assert_eq!(c.counters(), r.counters());
        let ok = r.counters();
        for bad in [
            ReplayCounters { head: 4, ..ok },
            ReplayCounters { len: 5, ..ok },
            ReplayCounters { inserted: 3, ..ok },
            ReplayCounters {
                head: 1,
                len: 3,
                inserted: 3,
                current_episode: 1,
            },
        ] {
            assert_eq!(c.set_counters(bad), Err(InvalidCounters), "{bad:?}");
        }
    }

    /// A batch of `C` chunks of 8 rows of sequences up to 4.
    type Chunks<const C: usize> = [BatchChunk<8, 4, 2, 1>; C];

    fn chunks<const C: usize>() -> Box<Chunks<C>> {
        bytemuck::zeroed_box()
    }

    #[test]
    fn one_step_rows_are_uniform_deterministic_and_cover_the_replay() {
        let mut r: Box<Replay<16, 2, 1>> = bytemuck::zeroed_box();
        r.begin_episode();
        for i in 0..10 {
            r.push(&t(i as f32));
        }
        let mode = BatchMode::OneStep { n: 1, gamma: 0.9 };
        let (mut a, mut b) = (chunks::<125>(), chunks::<125>());
        r.fill_batch(&mut Rng::seed_from_u64(9), &mut a[..], mode)
            .unwrap();
        r.fill_batch(&mut Rng::seed_from_u64(9), &mut b[..], mode)
            .unwrap();
        let mut seen = [0; 10];
        for (ca, cb) in a.iter().zip(b.iter()) {
            assert_eq!(ca.obs[0], cb.obs[0]);
            for n in 0..8 {
                let x = ca.obs[0][n][0];
                assert_eq!(ca.reward[0][n], x, "one step: the transition's own reward");
                assert_eq!(ca.next_obs[0][n], t(x).next_obs);
                assert_eq!(ca.bootstrap[0][n], 0.9);
                assert_eq!(ca.behaviour_log_prob[0][n], -x);
                seen[x as usize] += 1;
            }
        }
        assert!(seen.iter().all(|&c| c > 60), "{seen:?}");
    }

    /// Transition `i`: reward `i`, discount 0 after every seventh (a terminal), episodes of
    /// lengths 5, 9, 3, 12, ... so folds end at episode ends, at terminals and at the end of the
    /// stored data, in a ring that has wrapped.
    fn varied(r: &mut Replay<16, 2, 1>) -> std::vec::Vec<(Transition<2, 1>, u64)> {
        episodes(r, &[5, 9, 3, 12])
    }

    /// Episodes of the given lengths (transition `i` as in [`varied`]); the stored ones in age
    /// order with their episode numbers.
    fn episodes(
        r: &mut Replay<16, 2, 1>,
        lens: &[usize],
    ) -> std::vec::Vec<(Transition<2, 1>, u64)> {
        let mut all = std::vec::Vec::new();
        let mut i = 0;
        for (ep, &len) in lens.iter().enumerate() {
            r.begin_episode();
            for _ in 0..len {
                let mut x = t(i as f32);
                x.discount = if i % 7 == 6 { 0.0 } else { 1.0 };
                r.push(&x);
                all.push((x, ep as u64));
                i += 1;
            }
        }
        all.split_off(all.len() - 16)
    }

    #[test]
    fn n_step_rows_fold_what_follows_in_the_episode_written_out() {
        // Several episodes, and one episode longer than the ring (the newest transition's
        // successor in the ring is the oldest, of the same episode, yet not its successor).
        for lens in [&[5, 9, 3, 12][..], &[20]] {
            let mut r: Box<Replay<16, 2, 1>> = bytemuck::zeroed_box();
            let stored = episodes(&mut r, lens);
            assert_eq!(r.len(), 16);
            check_folds(&r, &stored);
        }
    }

    fn check_folds(r: &Replay<16, 2, 1>, stored: &[(Transition<2, 1>, u64)]) {
        let gamma = 0.9f64;
        for steps in [1u32, 3, 64] {
            let mut c = chunks::<40>();
            let mode = BatchMode::OneStep {
                n: steps,
                gamma: 0.9,
            };
            r.fill_batch(&mut Rng::seed_from_u64(steps as u64), &mut c[..], mode)
                .unwrap();
            for n in 0..8 * 40 {
                let (ch, row) = (&c[n / 8], n % 8);
                let x = ch.obs[0][row][0];
                let k = stored.iter().position(|(s, _)| s.obs[0] == x).unwrap();
                // Written out: rewards while in the same episode and stored, discounted by
                // gamma and the discounts before them.
                let (mut ret, mut mult, mut last) = (0f64, 1f64, k);
                let mut j = k;
                while j < stored.len() && j < k + steps as usize && stored[j].1 == stored[k].1 {
                    ret += mult * stored[j].0.reward as f64;
                    mult *= gamma * stored[j].0.discount as f64;
                    last = j;
                    j += 1;
                }
                assert!(
                    (ch.reward[0][row] as f64 - ret).abs() < 1e-4,
                    "n {steps}, row {n}"
                );
                assert!(
                    (ch.bootstrap[0][row] as f64 - mult).abs() < 1e-6,
                    "n {steps}, row {n}"
                );
                assert_eq!(
                    ch.next_obs[0][row], stored[last].0.next_obs,
                    "n {steps}, row {n}"
                );
                assert_eq!(ch.action[0][row], stored[k].0.action);
                assert_eq!(ch.behaviour_log_prob[0][row], -x);
            }
        }
    }

    /// Two episodes inserted in blocks of two (a fleet of two plants): with the interleave
    /// set to the other plant's block, every n-step row folds exactly its own episode's
    /// successors, as if the episode had been stored alone; without it the fold stops at the
    /// first foreign slot.
    #[test]
    fn interleaved_episodes_fold_their_own_successors() {
        let mut r: Box<Replay<64, 2, 1>> = bytemuck::zeroed_box();
        let (a, b) = (r.new_episode_id(), r.new_episode_id());
        let mut eps: [std::vec::Vec<Transition<2, 1>>; 2] = Default::default();
        for blk in 0..10 {
            for (e, id) in [(0usize, a), (1, b)] {
                for j in 0..2 {
                    let x = (100 * e + 2 * blk + j) as f32;
                    let mut tr = t(x);
                    tr.reward = 0.5 + x * 0.01;
                    r.push_to(id, &tr);
                    eps[e].push(tr);
                }
            }
        }
        for (interleave, whole) in [(2u64, true), (0, false)] {
            r.set_interleave(interleave);
            let mut c = chunks::<40>();
            let mode = BatchMode::OneStep { n: 5, gamma: 0.9 };
            r.fill_batch(&mut Rng::seed_from_u64(5), &mut c[..], mode)
                .unwrap();
            for n in 0..8 * 40 {
                let (ch, row) = (&c[n / 8], n % 8);
                let x = ch.obs[0][row][0];
                let e = usize::from(x >= 100.0);
                let k = eps[e].iter().position(|s| s.obs[0] == x).unwrap();
                // Contiguous fold stops at the block's end; the interleaved one goes on.
                let end = if whole { eps[e].len() } else { (k / 2) * 2 + 2 };
                let (mut ret, mut mult, mut last) = (0f32, 1f32, k);
                for j in k..(k + 5).min(end) {
                    ret += mult * eps[e][j].reward;
                    mult *= 0.9 * eps[e][j].discount;
                    last = j;
                }
                assert!((ch.reward[0][row] - ret).abs() < 1e-5, "row {n}: x {x}");
                assert!((ch.bootstrap[0][row] - mult).abs() < 1e-6, "row {n}");
                assert_eq!(ch.next_obs[0][row], eps[e][last].next_obs, "row {n}");
            }
        }
    }

    #[test]
    fn sequence_rows_are_consecutive_columns_of_one_episode() {
        let mut r: Box<Replay<16, 2, 1>> = bytemuck::zeroed_box();
        let stored = varied(&mut r);
        let mode = BatchMode::Sequences { len: 4, gamma: 0.5 };
        let mut c = chunks::<40>();
        r.fill_batch(&mut Rng::seed_from_u64(4), &mut c[..], mode)
            .unwrap();
        let mut starts = std::collections::BTreeSet::new();
        for ch in c.iter() {
            for row in 0..8 {
                let x = ch.obs[0][row][0];
                let k = stored.iter().position(|(s, _)| s.obs[0] == x).unwrap();
                starts.insert(k);
                for p in 0..4 {
                    let (s, ep) = &stored[k + p];
                    assert_eq!(*ep, stored[k].1, "inside one episode");
                    assert_eq!(ch.obs[p][row], s.obs);
                    assert_eq!(ch.action[p][row], s.action);
                    assert_eq!(ch.reward[p][row], s.reward);
                    assert_eq!(ch.next_obs[p][row], s.next_obs);
                    assert_eq!(ch.bootstrap[p][row], 0.5 * s.discount);
                    assert_eq!(ch.behaviour_log_prob[p][row], s.behaviour_log_prob);
                }
            }
        }
        // Stored (ages): 0 the 9-step episode's last transition, 1-3 the 3-step episode,
        // 4-15 the 12-step one; every start of a 4-sequence inside one episode is drawn.
        let valid: std::vec::Vec<usize> = (0..=12)
            .filter(|&k| stored[k].1 == stored[k + 3].1)
            .collect();
        assert_eq!(starts.into_iter().collect::<std::vec::Vec<_>>(), valid);
        // Exactly one episode of exactly the sequence length: its only start.
        let mut one: Box<Replay<16, 2, 1>> = bytemuck::zeroed_box();
        one.begin_episode();
        for i in 0..4 {
            one.push(&t(i as f32));
        }
        assert_eq!(
            one.sample_sequence_start(&mut Rng::seed_from_u64(1), 4),
            Ok(0)
        );
        assert_eq!(
            one.sample_sequence_start(&mut Rng::seed_from_u64(1), 5),
            Err(SampleError::NotEnoughData)
        );
        assert_eq!(
            one.sample_sequence_start(&mut Rng::seed_from_u64(1), 0),
            Err(SampleError::NotEnoughData)
        );
    }

    #[test]
    fn clear_empties_and_a_non_full_ring_restores() {
        let mut r: Box<Replay<16, 2, 1>> = bytemuck::zeroed_box();
        assert_eq!(r.capacity(), 16);
        r.begin_episode();
        for i in 0..5 {
            r.push(&t(i as f32));
        }
        // A ring that has not wrapped (len = inserted < CAP) restores.
        let ok = r.counters();
        let mut c: Box<Replay<16, 2, 1>> = bytemuck::zeroed_box();
        assert_eq!(c.set_counters(ok), Ok(()));
        assert_eq!(c.counters(), ok);
        r.clear();
        assert!(r.is_empty() && r.counters().len == 0 && r.inserted() == 0);
        let mut ch = chunks::<1>();
        let mode = BatchMode::OneStep { n: 1, gamma: 0.9 };
        let e = r.fill_batch(&mut Rng::seed_from_u64(1), &mut ch[..], mode);
        assert_eq!(e, Err(SampleError::NotEnoughData));
        r.push(&t(7.0));
        assert_eq!((r.len(), r.get(0)), (1, t(7.0)));
        assert_eq!(r.counters().head, 1, "pushes start again at slot 0");
        // Errors say what is wrong, each in its own words.
        use std::string::ToString;
        assert!(InvalidCounters.to_string().contains("counters"));
        assert!(SampleError::NotEnoughData.to_string().contains("too few"));
        assert_eq!(
            SampleError::NoSequence.to_string(),
            "no single-episode sequence of that length found"
        );
    }
}
