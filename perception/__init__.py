"""The AprilTag pipeline shared by the simulations and the hardware: OpenCV and numpy only, never MuJoCo."""
