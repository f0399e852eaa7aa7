from planner_client.cli import app

app(prog_name="m3p2i-planner")
