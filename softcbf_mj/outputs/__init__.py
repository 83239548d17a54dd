"""What a run leaves behind: the run folder and its time series, per-run figures, reports, rerun recordings, the plot
style and palette, progress lines. Imports no other room of `softcbf_mj`.
"""
