//! Metrics: checked against values computed independently (see tests/reference/metrics_ref.py).
