"""Process-level helpers below everything but the array maths: thread pinning, Ray, CLI value checks."""
