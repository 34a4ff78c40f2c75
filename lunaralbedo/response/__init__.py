"""Camera response recovery (seed 002): the aligned-stack command and its synthetic test scenes."""
