"""User studies: protocols, counterbalanced schedules, sessions, data and their analysis."""
