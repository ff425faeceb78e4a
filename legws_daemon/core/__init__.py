"""Pure, typed, vectorised mathematics: geometry, observer, certificate, Monte Carlo check."""
