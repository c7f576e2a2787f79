def grade(episode):
    while True:
        print("x" * 900)
