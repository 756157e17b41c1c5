"""Two frames in, one MotionEstimate out: pyramid, residuals, brightness, solvers, RANSAC, the coarse-to-fine estimate."""
