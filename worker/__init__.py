"""The job runner: claims measurement jobs from the service's database, measures in a child process,
reports stage and progress, and stores the result. Run it with ``canopy worker`` (or ``python -m worker``).
"""
