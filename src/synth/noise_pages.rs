//! The noise sources' deviates in pages of [`PAGE`] samples, each page a function of the
//! seed, its number and its shape only, so that any thread can draw it ahead.
//!
//! Why: the deviates are a quarter of the synthesiser's work, and they do not depend on
//! the stream. The DSP thread, after each block and while it waits for the next, draws the
//! pages the synthesiser will need next ([`PageFactory::work`]) and hands them over through a
//! lock-free queue; the synthesiser takes a page from the queue if it is there, and draws
//! it itself if not ([`NoisePages::prepare`]). Either way the page holds the same bits,
//! so the stream does not depend on who drew it, on timing, or on the block sizes.
//!
//! Page p of seed s holds, for the samples p·[`PAGE`] … (p + 1)·[`PAGE`] − 1:
//! - the thermal deviates, one per mode and sample, sample by sample, from a
//!   [`NormalSource`] whose state is SplitMix64 outputs 4 + 32·2p … of s;
//! - the detector's deviates, one per sample, from SplitMix64 outputs 4 + 32·(2p + 1) … .
//!
//! (Outputs 0 … 3 seed the start-up draw, [`NormalSource::set`]`(s, 2)`.) A page is drawn
//! for a number of modes; after a change of that number the synthesiser draws the pages
//! again for the new one, so a live change never reads a stale page.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use ringbuf::traits::{Consumer, Observer, Producer, Split};
use ringbuf::{HeapCons, HeapProd, HeapRb};

use super::normals::NormalSource;
use crate::physics::beam::MAX_MODES;

/// Samples per page: one block of the pipeline.
pub const PAGE: usize = 4096;

/// How far ahead of the synthesiser's page the factory draws: pages `on` + 2 … `on` +
/// `AHEAD`, 2.5 ms of stream at 10 MS/s, which rides over the DSP thread's longer pieces
/// of work (a spectrum, a plan change).
pub const AHEAD: u64 = 6;

/// Thermal deviates a page may hold: one per mode and sample, and the padding that the
/// last sample's lanes read past its modes (zeros, multiplied by zero coefficients).
const THERMAL_LEN: usize = PAGE * MAX_MODES + MAX_MODES;

/// What a page holds: whose it is, which page, and for what shape of stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PageKey {
    /// The noise seed (`/synth/seed`).
    pub seed: u64,
    /// Page number: samples `page`·[`PAGE`] onwards.
    pub page: u64,
    /// Thermal deviates per sample (the number of modes), 0 without thermal noise.
    pub modes: u8,
    /// Whether the page holds the detector's deviates.
    pub detector: bool,
}

impl PageKey {
    /// Whether a stream of this shape needs deviates at all.
    pub fn needs_deviates(&self) -> bool {
        self.modes > 0 || self.detector
    }

    /// The shape word published to the factory: modes, detector, and a "valid" bit.
    fn shape(&self) -> u64 {
        u64::from(self.modes) | u64::from(self.detector) << 8 | 1 << 9
    }

    fn with_shape(seed: u64, shape: u64, page: u64) -> Option<Self> {
        (shape & 1 << 9 != 0).then_some(Self {
            seed,
            page,
            modes: shape as u8,
            detector: shape & 1 << 8 != 0,
        })
    }
}

/// Draws the detector's deviates of page `page` of seed `seed` into `out` ([`PAGE`] long):
/// the same bits as a page drawn with them. Allocation-free.
pub fn draw_detector(seed: u64, page: u64, out: &mut [f32]) {
    NormalSource::splitmix_range(seed, 4 + 64 * page + 32).fill(&mut out[..PAGE]);
}

/// One page of deviates, in single precision: they are drawn in it
/// ([`super::normals`]), and half the bytes of `f64` is half the traffic between the thread
/// that draws a page and the one that reads it. Its buffers are allocated once
/// ([`NoisePage::new`]) and refilled for every key.
pub struct NoisePage {
    key: Option<PageKey>,
    thermal: Box<[f32]>,
    detector: Box<[f32]>,
}

impl std::fmt::Debug for NoisePage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NoisePage").field("key", &self.key).finish()
    }
}

impl Clone for NoisePage {
    fn clone(&self) -> Self {
        Self {
            key: self.key,
            thermal: self.thermal.clone(),
            detector: self.detector.clone(),
        }
    }
}

impl Default for NoisePage {
    fn default() -> Self {
        Self::new()
    }
}

impl NoisePage {
    /// An empty page (allocates its buffers).
    pub fn new() -> Self {
        Self {
            key: None,
            thermal: vec![0.0; THERMAL_LEN].into_boxed_slice(),
            detector: vec![0.0; PAGE].into_boxed_slice(),
        }
    }

    /// The page's key, `None` before its first draw.
    pub fn key(&self) -> Option<PageKey> {
        self.key
    }

    /// Draws the page for `key`. Allocation-free.
    pub fn draw(&mut self, key: PageKey) {
        let first = 4 + 64 * key.page;
        if key.modes > 0 {
            let len = PAGE * usize::from(key.modes);
            NormalSource::splitmix_range(key.seed, first).fill(&mut self.thermal[..len]);
        }
        if key.detector {
            draw_detector(key.seed, key.page, &mut self.detector);
        }
        self.key = Some(key);
    }

    /// The thermal deviates of page samples `from` … `from + len − 1` for `modes` modes,
    /// with the padding the last sample's lanes read after them.
    pub fn thermal(&self, from: usize, modes: usize) -> &[f32] {
        &self.thermal[from * modes..]
    }

    /// The detector's deviates of page samples `from` … .
    pub fn detector(&self, from: usize) -> &[f32] {
        &self.detector[from..]
    }
}

/// What the synthesiser needs, published for the factory.
#[derive(Debug, Default)]
struct Wanted {
    seed: AtomicU64,
    /// [`PageKey::shape`]; 0: nothing wanted.
    shape: AtomicU64,
    /// The page the synthesiser is on.
    page: AtomicU64,
}

/// The synthesiser's end of the page queue.
pub struct PageSupply {
    full: HeapCons<NoisePage>,
    empty: HeapProd<NoisePage>,
    wanted: Arc<Wanted>,
}

/// The end that draws pages ahead (the DSP thread, between blocks).
pub struct PageFactory {
    full: HeapProd<NoisePage>,
    empty: HeapCons<NoisePage>,
    wanted: Arc<Wanted>,
    /// The last page drawn.
    last: Option<PageKey>,
    /// Pages drawn.
    pub drawn: u64,
}

/// A page queue with [`AHEAD`] + 1 pages in it besides the synthesiser's own (allocates
/// them: 0.28 MB each, sized for [`MAX_MODES`] modes).
pub fn page_queue() -> (PageSupply, PageFactory) {
    let pages = AHEAD as usize + 1;
    // Room for every page in either queue, the synthesiser's own included, so a push
    // never fails.
    let (full_in, full_out) = HeapRb::<NoisePage>::new(pages + 1).split();
    let (mut empty_in, empty_out) = HeapRb::<NoisePage>::new(pages + 1).split();
    for _ in 0..pages {
        let _ = empty_in.try_push(NoisePage::new());
    }
    let wanted = Arc::new(Wanted::default());
    (
        PageSupply {
            full: full_out,
            empty: empty_in,
            wanted: wanted.clone(),
        },
        PageFactory {
            full: full_in,
            empty: empty_out,
            wanted,
            last: None,
            drawn: 0,
        },
    )
}

impl PageFactory {
    /// Draws the next page the synthesiser will need, if it is not more than [`AHEAD`]
    /// pages ahead and a buffer is free. Returns whether it drew one. Allocation-free and
    /// lock-free: for the DSP thread when it has nothing else to do.
    pub fn work(&mut self) -> bool {
        let seed = self.wanted.seed.load(Ordering::Acquire);
        let shape = self.wanted.shape.load(Ordering::Acquire);
        let on = self.wanted.page.load(Ordering::Acquire);
        let Some(wanted) = PageKey::with_shape(seed, shape, on) else {
            return false;
        };
        // Never the page after the synthesiser's own: it may need that one before this
        // thread could finish it, and then draws it itself (the race costs both threads
        // the work). From two pages on it has a whole page of synthesis to come.
        let next = match self.last {
            Some(last) if PageKey { page: on, ..last } == wanted => (last.page + 1).max(on + 2),
            _ => on + 2,
        };
        if next > on + AHEAD {
            return false;
        }
        let Some(mut page) = self.empty.try_pop() else {
            return false;
        };
        let key = PageKey {
            page: next,
            ..wanted
        };
        page.draw(key);
        // Never full: the queues have room for every page.
        let _ = self.full.try_push(page);
        self.last = Some(key);
        self.drawn += 1;
        true
    }
}

/// Counts of where the synthesiser's pages came from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PageCounts {
    /// Pages taken from the queue, drawn by another thread.
    pub taken: u64,
    /// Pages the synthesiser drew itself (none was ready).
    pub drawn: u64,
    /// Pages from the queue thrown away: stale (drawn for a page already past or a
    /// previous seed or shape).
    pub discarded: u64,
}

/// The synthesiser's deviates: the page it is reading, and the queue it takes pages from.
#[derive(Debug, Default)]
pub struct NoisePages {
    current: NoisePage,
    supply: Option<PageSupply>,
    /// Where the pages came from.
    pub counts: PageCounts,
}

impl std::fmt::Debug for PageSupply {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PageSupply")
            .field("ready", &self.full.occupied_len())
            .finish()
    }
}

impl Clone for NoisePages {
    /// A copy draws its own pages: the queue stays with the original.
    fn clone(&self) -> Self {
        Self {
            current: self.current.clone(),
            supply: None,
            counts: self.counts,
        }
    }
}

impl NoisePages {
    /// Pages drawn by their reader alone (allocates one page).
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes pages from `supply` from now on.
    pub fn attach(&mut self, supply: PageSupply) {
        self.supply = Some(supply);
    }

    /// Makes `key` the current page: kept if it is already, else taken from the queue if
    /// it is there, else drawn here. Allocation-free and lock-free.
    pub fn prepare(&mut self, key: PageKey) {
        if self.current.key == Some(key) {
            return;
        }
        let Some(supply) = &mut self.supply else {
            self.current.draw(key);
            self.counts.drawn += 1;
            return;
        };
        supply.wanted.seed.store(key.seed, Ordering::Relaxed);
        supply.wanted.shape.store(key.shape(), Ordering::Relaxed);
        // Release: the factory that reads the page reads the seed and shape with it.
        supply.wanted.page.store(key.page, Ordering::Release);
        while let Some(head) = supply.full.try_peek() {
            let head_key = head.key;
            if head_key.is_some_and(|k| {
                k.page > key.page
                    && PageKey {
                        page: key.page,
                        ..k
                    } == key
            }) {
                // A page still to come: left for later.
                break;
            }
            let Some(page) = supply.full.try_pop() else {
                break;
            };
            if head_key == Some(key) {
                let old = std::mem::replace(&mut self.current, page);
                let _ = supply.empty.try_push(old);
                self.counts.taken += 1;
                return;
            }
            let _ = supply.empty.try_push(page);
            self.counts.discarded += 1;
        }
        self.current.draw(key);
        self.counts.drawn += 1;
    }

    /// The current page.
    pub fn page(&self) -> &NoisePage {
        &self.current
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(page: u64) -> PageKey {
        PageKey {
            seed: 7,
            page,
            modes: 5,
            detector: true,
        }
    }

    #[test]
    fn a_page_is_a_function_of_its_key() {
        let (mut a, mut b) = (NoisePage::new(), NoisePage::new());
        a.draw(key(3));
        b.draw(key(2));
        assert_ne!(a.thermal[..PAGE * 5], b.thermal[..PAGE * 5]);
        b.draw(key(3));
        assert_eq!(a.thermal, b.thermal);
        assert_eq!(a.detector, b.detector);
        // The thermal and detector deviates are different streams.
        assert_ne!(a.thermal[..PAGE], a.detector[..]);
        // Padding after the last sample's modes: zeros.
        assert!(a.thermal[PAGE * 5..].iter().all(|&x| x == 0.0));
    }

    #[test]
    fn pages_drawn_ahead_are_the_pages_drawn_in_place() {
        let (supply, mut factory) = page_queue();
        let mut fed = NoisePages::new();
        fed.attach(supply);
        let mut alone = NoisePages::new();
        for p in 0..20 {
            // The factory gets to work on some pages only, as on a busy machine.
            if p % 3 != 1 {
                while factory.work() {}
            }
            fed.prepare(key(p));
            alone.prepare(key(p));
            assert_eq!(fed.page().key(), Some(key(p)));
            assert_eq!(fed.page().thermal, alone.page().thermal, "page {p}");
            assert_eq!(fed.page().detector, alone.page().detector, "page {p}");
        }
        let c = fed.counts;
        assert_eq!(c.taken + c.drawn, 20, "{c:?}");
        assert!(c.taken >= 10, "most pages came ahead: {c:?}");
        // A new seed: the pages drawn ahead for the old one are stale.
        while factory.work() {}
        let new = PageKey { seed: 8, ..key(20) };
        fed.prepare(new);
        alone.prepare(new);
        assert_eq!(fed.page().thermal, alone.page().thermal);
        assert!(fed.counts.discarded > c.discarded, "{:?}", fed.counts);
        // The factory follows the new seed (from page 22: page 21 is the synthesiser's).
        while factory.work() {}
        let taken = fed.counts.taken;
        fed.prepare(PageKey { page: 21, ..new });
        fed.prepare(PageKey { page: 22, ..new });
        assert_eq!(fed.counts.taken, taken + 1);
    }

    #[test]
    fn the_factory_stays_at_most_ahead_pages_ahead() {
        let (supply, mut factory) = page_queue();
        let mut fed = NoisePages::new();
        fed.attach(supply);
        assert!(!factory.work(), "nothing is wanted before the first page");
        fed.prepare(key(0));
        let mut n = 0;
        while factory.work() {
            n += 1;
        }
        // Pages 2 … AHEAD: page 1 is the synthesiser's to draw if it gets there first.
        assert_eq!(n, AHEAD - 1);
        fed.prepare(key(1));
        assert_eq!(fed.counts.drawn, 2);
        fed.prepare(key(2));
        assert_eq!(fed.counts.taken, 1);
        // Two pages on: two more pages to draw, AHEAD + 1 and AHEAD + 2.
        assert!(factory.work() && factory.work());
        assert!(!factory.work());
    }
}
