"""The application: the composition root, the control loop, lockstep and wall-clock runs."""
