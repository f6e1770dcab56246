"""Physics: MuJoCo robots with IMUs, the IMU error model, excitation, damage scenarios, the robot farm."""
