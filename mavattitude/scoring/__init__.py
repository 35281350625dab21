"""How an estimate is scored: accuracy statistics (metrics, and running_metrics in constant
memory for a live session), BROAD's error-quaternion measures, where the autopilot's own attitude
cannot be right (refcheck), inputs that cannot carry an attitude (imucheck), and rankings across
logs with their intervals and sign tests (rankstats)."""
