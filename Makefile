# Bootstrap is implicit: every target goes through ./uav-flock, which sets up .venv and ros2_ws once.
.PHONY: run test check bootstrap clean distclean

run:
	./uav-flock run

test:
	./uav-flock test

# The fast tier, what a contributor runs after each edit: the pure unit and property tests (`slow` left out,
# pytest.ini says what that is), under two minutes on two cores. `make test` stays the whole suite.
check:
	./uav-flock test -m "not slow" -q

bootstrap:
	./uav-flock bootstrap

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log ros2_ws/colcon.out ros2_ws/.uav-flock-stamp

distclean: clean
	rm -rf .venv
