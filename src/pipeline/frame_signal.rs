//! Wakes the consumer as soon as the DSP thread has handed out demodulator frames, so the
//! server does not wait for its next polling tick (up to 1 ms, 0.5 ms on average).
//!
//! On Linux it is an `eventfd`: the DSP thread's [`FrameSignal::notify`] is one
//! non-blocking `write` (no lock, no allocation), and the async side waits for the
//! descriptor to become readable. Elsewhere there is none ([`FrameSignal::new`] gives
//! `None`) and the consumer polls.

#[cfg(target_os = "linux")]
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};

/// A wake-up from the DSP thread to the consumer of its frames.
#[derive(Debug)]
pub struct FrameSignal {
    #[cfg(target_os = "linux")]
    fd: OwnedFd,
}

impl FrameSignal {
    /// A new signal, or `None` where the system has none (not Linux, or out of
    /// descriptors).
    pub fn new() -> Option<Self> {
        #[cfg(target_os = "linux")]
        {
            // SAFETY: eventfd takes no pointers; a non-negative result is a new descriptor
            // that nothing else owns.
            let fd = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
            if fd < 0 {
                return None;
            }
            // SAFETY: `fd` was just opened and is owned here alone.
            Some(Self {
                fd: unsafe { OwnedFd::from_raw_fd(fd) },
            })
        }
        #[cfg(not(target_os = "linux"))]
        None
    }

    /// Wakes the consumer (called on the DSP thread: one non-blocking syscall).
    pub fn notify(&self) {
        #[cfg(target_os = "linux")]
        {
            let one: u64 = 1;
            // SAFETY: writes 8 bytes from a live u64 to a descriptor owned by `self`. It
            // cannot block (EFD_NONBLOCK); a full counter (2^64 − 2 unread wake-ups) cannot
            // happen while anyone reads, and a lost wake-up only costs a polling tick.
            let _ = unsafe { libc::write(self.fd.as_raw_fd(), (&one as *const u64).cast(), 8) };
        }
    }

    /// Takes every pending wake-up. Always ends with the error `WouldBlock` once none is
    /// left, which is what tokio's `AsyncFd::try_io` needs to clear the readiness it saw.
    pub fn drain(&self) -> std::io::Result<()> {
        #[cfg(target_os = "linux")]
        loop {
            let mut count: u64 = 0;
            // SAFETY: reads 8 bytes into a live u64 from a descriptor owned by `self`.
            let n = unsafe { libc::read(self.fd.as_raw_fd(), (&mut count as *mut u64).cast(), 8) };
            if n < 0 {
                return Err(std::io::Error::last_os_error());
            }
        }
        #[cfg(not(target_os = "linux"))]
        Err(std::io::ErrorKind::WouldBlock.into())
    }
}

#[cfg(target_os = "linux")]
impl AsRawFd for FrameSignal {
    fn as_raw_fd(&self) -> RawFd {
        self.fd.as_raw_fd()
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn notifications_are_counted_and_drained() {
        let s = FrameSignal::new().expect("eventfd");
        assert_eq!(
            s.drain().unwrap_err().kind(),
            std::io::ErrorKind::WouldBlock
        );
        s.notify();
        s.notify();
        // Readable now: poll says so without waiting.
        let mut p = libc::pollfd {
            fd: s.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one live pollfd.
        assert_eq!(unsafe { libc::poll(&mut p, 1, 0) }, 1);
        assert_eq!(
            s.drain().unwrap_err().kind(),
            std::io::ErrorKind::WouldBlock
        );
        p.revents = 0;
        // SAFETY: as above.
        assert_eq!(unsafe { libc::poll(&mut p, 1, 0) }, 0, "drained");
    }
}
