"""What a measurement is shown as: its figures, made by the worker with the measurement, and its report."""
