"""Services: the logic behind the routes. Each takes the session first and never commits."""
