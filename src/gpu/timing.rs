//! Timing GPU work: each run encodes the work, submits it and waits for the GPU; medians of the
//! wall clock (submit to idle) and, where the adapter has timestamp queries inside encoders, of
//! the GPU's own timestamps around the work. Used by a climb's live pass ([`super::live`]), the
//! benchmarks, and the CompenNet stage choosing its convolution kernels ([`super::ConvKernels`]).

use std::time::Instant;

use serde::Serialize;

use super::GpuContext;
use crate::error::{Error, Result};

/// Medians of one measurement, milliseconds.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Timing {
    /// Submit to GPU idle, wall clock.
    pub wall_ms: f64,
    /// Between GPU timestamps before and after the work, when the adapter has them.
    pub gpu_ms: Option<f64>,
}

impl Timing {
    /// The GPU time where measured, else the wall time.
    pub fn best_ms(&self) -> f64 {
        self.gpu_ms.unwrap_or(self.wall_ms)
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return f64::NAN;
    }
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Times `record` (which encodes one frame's work): `warmup` untimed runs, then `iters` timed.
pub fn time_work(
    ctx: &GpuContext,
    warmup: usize,
    iters: usize,
    mut record: impl FnMut(&mut wgpu::CommandEncoder) -> Result<()>,
) -> Result<Timing> {
    let stamps = ctx.device.features().contains(
        wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS,
    );
    let query = stamps.then(|| {
        let set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("bench"),
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let resolve = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bench resolve"),
            size: 16,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let read = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bench read"),
            size: 16,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        (set, resolve, read)
    });
    let period_ns = ctx.queue.get_timestamp_period() as f64;
    let (mut walls, mut gpus) = (Vec::new(), Vec::new());
    for i in 0..warmup + iters {
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("bench"),
            });
        if let Some((set, _, _)) = &query {
            enc.write_timestamp(set, 0);
        }
        record(&mut enc)?;
        if let Some((set, resolve, read)) = &query {
            enc.write_timestamp(set, 1);
            enc.resolve_query_set(set, 0..2, resolve, 0);
            enc.copy_buffer_to_buffer(resolve, 0, read, 0, 16);
        }
        let t = Instant::now();
        ctx.queue.submit([enc.finish()]);
        ctx.wait()?;
        let wall = t.elapsed().as_secs_f64() * 1e3;
        let gpu = match &query {
            Some((_, _, read)) => {
                let ticks = ctx.map_read(read, |bytes| {
                    let v: &[u64] = bytemuck::try_cast_slice(bytes)
                        .map_err(|e| Error::Failed(format!("GPU timestamps layout: {e}")))?;
                    Ok([v[0], v[1]])
                })?;
                Some(ticks[1].saturating_sub(ticks[0]) as f64 * period_ns / 1e6)
            }
            None => None,
        };
        if i >= warmup {
            walls.push(wall);
            if let Some(g) = gpu {
                gpus.push(g);
            }
        }
    }
    Ok(Timing {
        wall_ms: median(walls),
        gpu_ms: (!gpus.is_empty()).then(|| median(gpus)),
    })
}
