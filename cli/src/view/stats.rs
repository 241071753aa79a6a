//! What a viewer run measured: frame intervals and GI latencies (a light change to the first
//! presented frame whose indirect light answers it).

use serde_json::{Value, json};

#[derive(Debug, Default, Clone)]
pub struct Stats {
    pub adapter: String,
    pub surface: String,
    pub source: String,
    pub patches: usize,
    pub triangles: usize,
    pub width: u32,
    pub height: u32,
    /// Milliseconds between successive presents.
    pub frame_ms: Vec<f64>,
    /// Milliseconds from a light change to the frame that shows its indirect light.
    pub gi_latency_ms: Vec<f64>,
    /// From the window's first frame to the first frame with indirect light.
    pub first_indirect_ms: Option<f64>,
    pub frames: u64,
    pub screenshot: Option<String>,
}

/// The `q`-quantile (0..=1) by nearest rank; `None` when empty.
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
    Some(v[rank - 1])
}

impl Stats {
    pub fn json(&self) -> Value {
        let summary = |v: &[f64]| {
            json!({
                "count": v.len(),
                "median": quantile(v, 0.5),
                "p90": quantile(v, 0.9),
                "p99": quantile(v, 0.99),
                "max": quantile(v, 1.0),
            })
        };
        json!({
            "adapter": self.adapter,
            "surface": self.surface,
            "source": self.source,
            "patches": self.patches,
            "triangles": self.triangles,
            "width": self.width,
            "height": self.height,
            "frames": self.frames,
            "frame_ms": summary(&self.frame_ms),
            "gi_latency_ms": summary(&self.gi_latency_ms),
            "gi_latency_samples_ms": self.gi_latency_ms,
            "first_indirect_ms": self.first_indirect_ms,
            "screenshot": self.screenshot,
        })
    }

    pub fn summary(&self) -> String {
        let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.1}"));
        format!(
            "{} frames at {}×{} on {}: frame {} ms median, {} ms p99; GI latency {} ms median, \
             {} ms max over {} changes; first indirect light after {} ms",
            self.frames,
            self.width,
            self.height,
            self.adapter,
            f(quantile(&self.frame_ms, 0.5)),
            f(quantile(&self.frame_ms, 0.99)),
            f(quantile(&self.gi_latency_ms, 0.5)),
            f(quantile(&self.gi_latency_ms, 1.0)),
            self.gi_latency_ms.len(),
            f(self.first_indirect_ms),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_by_nearest_rank() {
        let v = [5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(quantile(&v, 0.5), Some(3.0));
        assert_eq!(quantile(&v, 0.0), Some(1.0));
        assert_eq!(quantile(&v, 1.0), Some(5.0));
        assert_eq!(quantile(&[], 0.5), None);
    }
}
