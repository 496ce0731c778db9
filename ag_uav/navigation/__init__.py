"""What the controller flies on: the feedback seam (true state or an estimate), the estimator banks
fed by GNSS, bearings or the planned route."""
