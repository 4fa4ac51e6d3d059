"""The toy maze study of paper Fig. 2: BC fails under an imitation gap (see maze.study)."""
