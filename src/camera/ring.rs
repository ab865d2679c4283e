//! Memory-mapped V4L2 capture buffers (Linux): the driver fills them in turn, compend reads one
//! at a time and gives it back before asking for the next.
//!
//! Written on the `v4l` crate's ioctl bindings rather than its `Stream`, which re-queues a
//! buffer still queued after a poll timeout (every later grab then fails with EINVAL) and
//! panics when dropped after an I/O error other than ENODEV. Here a timeout leaves the ring
//! usable, and dropping it ignores errors (the device may be gone).

use std::io;
use std::os::fd::RawFd;
use std::time::Duration;

use v4l::v4l_sys::{
    V4L2_BUF_FLAG_ERROR, v4l2_buf_type_V4L2_BUF_TYPE_VIDEO_CAPTURE, v4l2_buffer,
    v4l2_memory_V4L2_MEMORY_MMAP, v4l2_requestbuffers,
};
use v4l::v4l2::vidioc;

use super::RawFrame;

/// `ioctl` on `fd` with `arg`, retried when a signal interrupts it.
pub(super) fn xioctl<T>(fd: RawFd, request: vidioc::_IOC_TYPE, arg: &mut T) -> io::Result<()> {
    loop {
        // SAFETY: `arg` is a live, exclusively borrowed value of the type the request expects
        // (the callers pair each request with its struct from the kernel headers' bindings).
        let r = unsafe { v4l::v4l2::ioctl(fd, request, arg as *mut T as *mut std::ffi::c_void) };
        match r {
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            r => return r,
        }
    }
}

/// A zero-initialised kernel struct.
pub(super) fn zeroed<T: Copy>() -> T {
    // SAFETY: only used for the plain C structs of the V4L2 bindings (integers, arrays and
    // unions of those, raw pointers), for which all-zero bytes is a valid value.
    unsafe { std::mem::zeroed() }
}

/// One mapped buffer.
struct Mapped {
    ptr: *mut std::ffi::c_void,
    len: usize,
}

/// The ring of mapped buffers of one open device, streaming.
pub(super) struct Ring {
    fd: RawFd,
    bufs: Vec<Mapped>,
    /// The buffer compend holds (dequeued, not yet given back).
    held: Option<u32>,
    streaming: bool,
}

// SAFETY: the mappings are the process's, valid from any thread; the ring is used by one thread
// at a time (`&mut self`), and the slices it hands out borrow it.
unsafe impl Send for Ring {}

fn desc(index: u32) -> v4l2_buffer {
    let mut b: v4l2_buffer = zeroed();
    b.index = index;
    b.type_ = v4l2_buf_type_V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = v4l2_memory_V4L2_MEMORY_MMAP;
    b
}

impl Ring {
    /// Allocates and maps `count` buffers on `fd` (the driver may give more or fewer), queues
    /// them and starts streaming. The ring does not own `fd`: it must outlive the ring.
    pub(super) fn start(fd: RawFd, count: u32) -> io::Result<Self> {
        let mut req: v4l2_requestbuffers = zeroed();
        req.count = count;
        req.type_ = v4l2_buf_type_V4L2_BUF_TYPE_VIDEO_CAPTURE;
        req.memory = v4l2_memory_V4L2_MEMORY_MMAP;
        xioctl(fd, vidioc::VIDIOC_REQBUFS, &mut req)?;
        if req.count == 0 {
            return Err(io::Error::other("the driver gave no capture buffers"));
        }
        let mut ring = Self {
            fd,
            bufs: Vec::new(),
            held: None,
            streaming: false,
        };
        for index in 0..req.count {
            let mut b = desc(index);
            xioctl(fd, vidioc::VIDIOC_QUERYBUF, &mut b)?;
            let len = b.length as usize;
            // SAFETY: maps the driver's buffer `index` at the offset it gave; the mapping is
            // released in `Drop` and only read while the buffer is dequeued.
            let ptr = unsafe {
                v4l::v4l2::mmap(
                    std::ptr::null_mut(),
                    len,
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_SHARED,
                    fd,
                    b.m.offset as libc::off_t,
                )?
            };
            ring.bufs.push(Mapped { ptr, len });
        }
        for index in 0..req.count {
            xioctl(fd, vidioc::VIDIOC_QBUF, &mut desc(index))?;
        }
        let mut typ = v4l2_buf_type_V4L2_BUF_TYPE_VIDEO_CAPTURE;
        xioctl(fd, vidioc::VIDIOC_STREAMON, &mut typ)?;
        ring.streaming = true;
        Ok(ring)
    }

    /// Waits at most `timeout` for `fd` to have a filled buffer. `Ok(false)`: timed out.
    fn wait(&self, timeout: Duration) -> io::Result<bool> {
        let ms = timeout.as_millis().min(i32::MAX as u128) as i32;
        let mut p = libc::pollfd {
            fd: self.fd,
            events: libc::POLLIN,
            revents: 0,
        };
        loop {
            // SAFETY: one valid pollfd, count 1.
            let r = unsafe { libc::poll(&mut p, 1, ms) };
            if r >= 0 {
                return Ok(r > 0);
            }
            let e = io::Error::last_os_error();
            if e.kind() != io::ErrorKind::Interrupted {
                return Err(e);
            }
        }
    }

    /// The next filled buffer, waiting at most `timeout`; the previous one is given back to
    /// the driver first. `TimedOut` when nothing came; the OS error otherwise (ENODEV, EIO:
    /// the device went away).
    pub(super) fn next(&mut self, timeout: Duration) -> io::Result<RawFrame<'_>> {
        if let Some(index) = self.held.take() {
            xioctl(self.fd, vidioc::VIDIOC_QBUF, &mut desc(index))?;
        }
        if !self.wait(timeout)? {
            return Err(io::Error::new(
                io::ErrorKind::TimedOut,
                "no frame from the driver",
            ));
        }
        let mut b = desc(0);
        xioctl(self.fd, vidioc::VIDIOC_DQBUF, &mut b)?;
        let Some(m) = self.bufs.get(b.index as usize) else {
            return Err(io::Error::other(format!(
                "the driver returned buffer {} of {}",
                b.index,
                self.bufs.len()
            )));
        };
        self.held = Some(b.index);
        let used = (b.bytesused as usize).min(m.len);
        // SAFETY: the buffer is mapped for `m.len` bytes and dequeued: the driver does not
        // write it until it is queued again, which needs `&mut self` (the slice borrows self).
        let data = unsafe { std::slice::from_raw_parts(m.ptr as *const u8, used) };
        let sec = u64::try_from(b.timestamp.tv_sec).unwrap_or(0);
        let usec = u64::try_from(b.timestamp.tv_usec).unwrap_or(0).min(999_999);
        Ok(RawFrame {
            data,
            sequence: b.sequence,
            timestamp: Duration::from_secs(sec) + Duration::from_micros(usec),
            error: b.flags & V4L2_BUF_FLAG_ERROR != 0,
        })
    }
}

impl Drop for Ring {
    /// Stops streaming and releases the buffers, ignoring errors: after an unplug every call
    /// fails, and there is nothing left to release on the driver's side.
    fn drop(&mut self) {
        if self.streaming {
            let mut typ = v4l2_buf_type_V4L2_BUF_TYPE_VIDEO_CAPTURE;
            let _ = xioctl(self.fd, vidioc::VIDIOC_STREAMOFF, &mut typ);
        }
        for m in self.bufs.drain(..) {
            // SAFETY: each mapping was made by `start` with this length and is unmapped once.
            let _ = unsafe { v4l::v4l2::munmap(m.ptr, m.len) };
        }
        let mut req: v4l2_requestbuffers = zeroed();
        req.type_ = v4l2_buf_type_V4L2_BUF_TYPE_VIDEO_CAPTURE;
        req.memory = v4l2_memory_V4L2_MEMORY_MMAP;
        let _ = xioctl(self.fd, vidioc::VIDIOC_REQBUFS, &mut req);
    }
}
