"""Hardware mode: the valve-board link and the loop that runs the controller under test on a real arm (never MuJoCo)."""
