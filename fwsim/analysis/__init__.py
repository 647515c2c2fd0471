"""What a log says: metrics, comparisons, batch reports and plots (all read logs only)."""
